"""The base class of every config section (kept apart so subsystems can import it cheaply)."""

from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict, SerializationInfo, SerializerFunctionWrapHandler, model_serializer, model_validator

RECORD = {"record": True}
"""Serialization context of a config *record* (what a run key and a manifest hold): see `record`."""


class Section(BaseModel):
    """Base of every config section: unknown keys and loose types are errors, not guesses.

    `omit_at_default` names fields added after results were stored, with the value that leaves
    behaviour as it was. A record (`record`) leaves them out at that value, so the run keys of
    the runs made before them stay valid; every other dump (e.g. `d2a config show`) shows them.

    Retiring a setting (an experiment that did not become a default) deletes its field and code
    and names it in `retired` with the value that behaves as d2a does now: stored records that
    carry it at that value still validate (the key is dropped), any other value is an error
    naming the key. A retired key that every record held (it had no neutral value to leave out)
    goes in `recorded_constants` instead: records still write it at that value, so run keys and
    artifact ids made before the retirement stay the same."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)
    omit_at_default: ClassVar[dict[str, Any]] = {}
    retired: ClassVar[dict[str, Any]] = {}
    recorded_constants: ClassVar[dict[str, Any]] = {}

    @model_validator(mode="before")
    @classmethod
    def _accept_retired_at_their_value(cls, data: Any) -> Any:
        gone = {**cls.retired, **cls.recorded_constants}
        if not isinstance(data, dict) or not gone.keys() & data.keys():
            return data
        for name in gone.keys() & data.keys():
            if data[name] != gone[name]:
                raise ValueError(f"'{name}' is a retired setting (docs/experiments/README.md); it can only be "
                                 f"{gone[name]!r}, which is what d2a does now, got {data[name]!r}")
        return {k: v for k, v in data.items() if k not in gone}

    @model_serializer(mode="wrap")
    def _leave_out_neutral_additions(self, handler: SerializerFunctionWrapHandler, info: SerializationInfo) -> Any:
        data = handler(self)
        if isinstance(data, dict) and isinstance(info.context, dict) and info.context.get("record"):
            for name, neutral in self.omit_at_default.items():
                if name in data and data[name] == neutral:
                    del data[name]
            data.update(self.recorded_constants)
        return data


def record(section: BaseModel) -> dict[str, Any]:
    """The section as a config record: JSON types, neutral later additions left out."""
    return section.model_dump(mode="json", context=RECORD)


def stored_dump(section_type: type[BaseModel], stored: dict[str, Any], what: str) -> dict[str, Any]:
    """A stored record (or an older whole dump) of `section_type` as `model_dump(mode="json")`
    gives it today: left-out fields at their defaults, nested sections whole. `what` names the
    file in the error when it no longer validates (a retired setting at another value)."""
    from pydantic import ValidationError

    from d2a_core.errors import ConfigError

    try:
        return section_type.model_validate(stored).model_dump(mode="json")
    except ValidationError as error:
        raise ConfigError(f"{what}: its config no longer validates: {error}") from None
