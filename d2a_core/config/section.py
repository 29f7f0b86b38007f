"""The base class of every config section (kept apart so subsystems can import it cheaply)."""

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, SerializationInfo, SerializerFunctionWrapHandler, model_serializer

RECORD = {"record": True}
"""Serialization context of a config *record* (what a run key and a manifest hold): see `record`."""


class Section(BaseModel):
    """Base of every config section: unknown keys and loose types are errors, not guesses.

    `omit_at_default` names fields added after results were stored, with the value that leaves
    behaviour as it was. A record (`record`) leaves them out at that value, so the run keys of
    the runs made before them stay valid; every other dump (e.g. `d2a config show`) shows them."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)
    omit_at_default: ClassVar[dict[str, Any]] = {}

    @model_serializer(mode="wrap")
    def _leave_out_neutral_additions(self, handler: SerializerFunctionWrapHandler, info: SerializationInfo) -> Any:
        data = handler(self)
        if isinstance(data, dict) and isinstance(info.context, dict) and info.context.get("record"):
            for name, neutral in self.omit_at_default.items():
                if name in data and data[name] == neutral:
                    del data[name]
        return data


def record(section: BaseModel) -> dict[str, Any]:
    """The section as a config record: JSON types, neutral later additions left out."""
    return section.model_dump(mode="json", context=RECORD)
