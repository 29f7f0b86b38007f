"""Content-addressed artifact store: blobs by sha256, manifests with lineage, aliases, verify, gc."""

from d2a_core.artifacts.manifest import Artifact, artifact_id, canonical_json, code_version, content_key
from d2a_core.artifacts.store import ArtifactWriter, GcReport, Store, VerifyProblem

__all__ = ["Artifact", "ArtifactWriter", "GcReport", "Store", "VerifyProblem", "artifact_id", "canonical_json", "code_version",
           "content_key"]
