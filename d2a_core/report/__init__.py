"""`d2a report`: the paper's tables and figures from stored artifacts, beside the paper's numbers.

Modules, one job each: `collect` (find and read artifacts), `presets` (which preset made them),
`stats` (bootstrap CI, IQM), `paper` (the published values in `paper_values.yaml`), `tables`
(the tables as data), `figures` (matplotlib), `render` (Markdown and HTML), `build` (the report
artifact). Reads JSON, JSONL, NPZ and MCAP files only: no torch, no simulator.
"""

from d2a_core.report.build import LATEST, build_report

__all__ = ["LATEST", "build_report"]
