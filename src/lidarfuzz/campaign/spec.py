"""A campaign, as a user writes it: what data, which system, which operators at which
severities, which relations, which seed. YAML or JSON, validated by pydantic; an error names
the file and the offending key (``operators.1.severities.0``).

Example (``campaign.yaml``)::

    name: fog-vs-classic
    dataset: sim                # a registered data set, or a path
    sut: classic                # a registered model, or a SUT spec
    operators:                  # or auto: the default set (lidarfuzz.campaign.defaults)
      - name: fog
        severities: [1, 3, 5]
      - name: rotate_z          # the thesis's names work too (RAR)
        config: {angle_range: [10, 20]}
    relations: auto             # every relation that applies to each operator, or a list:
                                #   [preservation, {name: invariance, config: {min_iou: 0.3}}]
    seed: 0
    frames: 50                  # the first 50 frames (all when left out)
    frame_order: first          # or random: 50 frames drawn with the seed (kept in data-set order)
    reference: classic-v1       # optional: a system (or a list) run on the same mutants, compared in the report
    pilot: 5                    # optional: a 5-frame pilot first; settings whose floor leaves no room are
                                #   lowered or dropped (lidarfuzz.campaign.pilot)

A structural campaign (``kind: structural``, :mod:`lidarfuzz.campaign.structural`)::

    kind: structural
    dataset: [drive-0, drive-1]  # field-test logs (one, or a list), replayed in order
    sut: controller              # a sequence system
    coverage:
      targets: [lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process]
    segments: 5
    heuristics: [greedy_edges, decision_change, random]
    strategies: [HGT, AVG]
"""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from lidarfuzz.campaign.kinds import DEFAULT_KIND, TASK_KINDS, find_kind, task_kind
from lidarfuzz.errors import DataFormatError, validation_error
from lidarfuzz.io.guards import reading
from lidarfuzz.io.textfiles import load_structured


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)


class FieldError(ValueError):
    """A problem at a key below the one pydantic reports (an operator's ``config.share_range.1``, or
    one entry of the operator list): :func:`parse_campaign` names the whole path.

    Args:
        loc: The path below the reporting key (``("config", "share_range", 1)``).
        message: What is wrong.
    """

    def __init__(self, loc: tuple[str | int, ...], message: str) -> None:
        super().__init__(message)
        self.loc, self.message = loc, message


def _severity_setting(name: str, severity: int) -> str:
    """The configuration ``severity`` gives operator ``name``, as comparable text."""
    from lidarfuzz.operators import get

    return json.dumps(get(name).at_severity(severity).config.model_dump(mode="json"), sort_keys=True)


class OperatorChoice(_Model):
    """One operator: at the listed severities, or once with an explicit config."""

    name: str = Field(description="operator name or alias (lidarfuzz operators)")
    severities: list[int] = Field(default_factory=lambda: [1, 3, 5], description="severities 1–5")
    config: dict[str, Any] | None = Field(default=None, description="config fields instead of severities")

    @field_validator("name")
    @classmethod
    def _known(cls, name: str) -> str:
        from lidarfuzz.operators import available, get

        try:
            return get(name).name
        except KeyError:  # the registry's message ends in CLI advice; a campaign's error names the choices
            raise ValueError(f"unknown operator {name!r}; known: {', '.join(sorted(available()))}") from None

    @field_validator("severities")
    @classmethod
    def _severities(cls, values: list[int]) -> list[int]:
        if not values:
            raise ValueError("give at least one severity")
        bad = [v for v in values if not 1 <= v <= 5]
        if bad:
            raise ValueError(f"severities are 1 to 5, got {bad}")
        return sorted(set(values))

    @model_validator(mode="after")
    def _config_builds(self) -> OperatorChoice:
        """A config must build the operator: a field out of its range (a share above 1) is refused
        at ``config.<field>``, as pydantic names it."""
        if self.config is not None:
            from lidarfuzz.operators import get

            try:
                get(self.name)(**self.config)
            except ValidationError as exc:
                first = exc.errors()[0]
                more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
                raise FieldError(("config", *first["loc"]), f"{self.name}: {first['msg']}{more}") from None
        return self

    @model_validator(mode="before")
    @classmethod
    def _default_severities(cls, data: Any) -> Any:
        """The default severities less those that configure the operator as an earlier one does
        (``global_flip`` mirrors at every severity: severity 1 only)."""
        if (not isinstance(data, dict) or "severities" in data or data.get("config") is not None
                or not isinstance(data.get("name"), str)):
            return data  # a name that is no string is refused by its own validator
        from lidarfuzz.campaign.defaults import DEFAULT_SEVERITIES, distinct_severities

        try:
            return {**data, "severities": distinct_severities(data["name"], DEFAULT_SEVERITIES)}
        except (KeyError, TypeError):
            return data  # an unknown name is refused by its own validator

    @model_validator(mode="after")
    def _distinct_severities(self) -> OperatorChoice:
        """Severities that configure the operator the same way (a mirror is a mirror at every
        severity) would run the same mutants twice: refused, naming the operator."""
        if self.config is not None:
            return self
        settings: dict[str, int] = {}
        same: list[int] = []
        for severity in self.severities:
            key = _severity_setting(self.name, severity)
            if key in settings:
                same.append(severity)
            else:
                settings[key] = severity
        if not same:
            return self
        first = min(settings.values())
        raise FieldError(("severities",), f"{self.name} is configured the same way at severities "
                                            f"{', '.join(map(str, sorted([first, *same])))}: give one of them")


class RelationChoice(_Model):
    """A relation with a configuration (``lidarfuzz relations NAME`` lists its fields)."""

    name: str
    config: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _builds(self) -> RelationChoice:
        from lidarfuzz.oracles.relations import get

        try:
            cls = get(self.name)
        except KeyError as exc:
            raise ValueError(str(exc)) from None
        cls(**self.config)  # a bad field raises here, named by pydantic
        return self.model_copy(update={"name": cls.name}) if cls.name != self.name else self


class CampaignSpec(_Model):
    """What to run."""

    name: str = ""
    dataset: str = Field(description="registered data set name, or a path to data")
    sut: str = Field(description="registered model name, or a SUT spec (lidarfuzz suts)")
    kind: str = Field(default=DEFAULT_KIND, description="; ".join(f"{k.name}: {k.help}" for k in TASK_KINDS))
    operators: list[OperatorChoice] = Field(
        default_factory=list, validate_default=True,
        description="mutation: what to run (auto: the default set, lidarfuzz.campaign.defaults); guided / fuzz: "
                    "the operator pool (default pool if empty)")
    search: dict[str, Any] = Field(
        default_factory=dict, description="guided / fuzz: budget, criteria, guide, max_failed_tries, batch, ...")
    relations: Literal["auto"] | list[str | RelationChoice] = Field(
        default="auto", description="auto, or relation names and {name, config} entries")
    seed: int = Field(default=0, ge=0)  # numpy's SeedSequence takes non-negative integers only
    trials: int = Field(default=1, ge=1, le=100, description="mutants per frame and severity")
    frames: int | None = Field(default=None, ge=1, description="only N frames (see frame_order)")
    pilot: int | None = Field(
        default=None, ge=1, description="first a pilot on N frames (on the reference when there is one): "
                                         "operator settings whose floor leaves no room at the campaign's frame "
                                         "count are lowered or dropped (lidarfuzz.campaign.pilot)")
    frame_order: Literal["first", "random"] = Field(
        default="first", description="with frames: the first N, or N drawn at random with the seed")
    reference: list[str] = Field(
        default_factory=list, description="differential testing: systems (registered model names or SUT specs) "
                                          "each run as a task of its own on the same frames, operators and seed; "
                                          "the report compares the system's violation rates and AP with theirs")
    logs: list[str] = Field(default_factory=list, description="structural: further field-test logs after dataset "
                                                              "(dataset: [a, b] says the same)")
    coverage: dict[str, Any] = Field(
        default_factory=dict, description="structural: targets (the code to cover) and optionally budget_frames, "
                                          "height, severity, radius, timeout")
    segments: int | None = Field(default=None, ge=1, description="structural: frames per segment (default 5)")
    heuristics: list[str] = Field(default_factory=list, description="structural: segment-selection heuristics "
                                                                    "(default all five)")
    strategies: list[str] = Field(default_factory=list, description="structural: log-generation strategies "
                                                                    "(default HGT, AVG)")

    @model_validator(mode="before")
    @classmethod
    def _several_logs(cls, data: Any) -> Any:
        if isinstance(data, dict) and isinstance(data.get("dataset"), list) and data["dataset"]:
            first, *rest = data["dataset"]
            return {**data, "dataset": first, "logs": [*rest, *data.get("logs", [])]}
        return data

    @field_validator("reference", mode="before")
    @classmethod
    def _one_or_more(cls, value: Any) -> Any:
        return [value] if isinstance(value, str) else value

    @field_validator("reference")
    @classmethod
    def _references(cls, value: list[str]) -> list[str]:
        blank = [i for i, ref in enumerate(value) if not ref.strip()]
        if blank:
            raise ValueError(f"entry {blank[0]} is empty: name a registered model or a SUT spec")
        return value

    @field_validator("kind")
    @classmethod
    def _known_kind(cls, value: str) -> str:
        try:
            return task_kind(value).name
        except ValueError as exc:
            raise ValueError(str(exc)) from None

    @field_validator("operators", mode="before")
    @classmethod
    def _default_set(cls, value: Any) -> Any:
        if value == "auto":
            from lidarfuzz.campaign.defaults import default_operators

            return default_operators()
        return value

    @field_validator("operators")
    @classmethod
    def _operators(cls, value: list[OperatorChoice], info: ValidationInfo) -> list[OperatorChoice]:
        kind = find_kind(info.data.get("kind", DEFAULT_KIND))
        if kind is not None and kind.requires_operators and not value:
            raise ValueError(f"a {kind.name} campaign needs at least one operator")
        if kind is not None:
            from lidarfuzz.operators import get

            for choice in value:
                modality = get(choice.name).modality
                if modality != kind.modality:
                    raise ValueError(f"{choice.name} is a {modality} operator; a {kind.name} campaign runs on "
                                     f"{kind.modality} data: choose {kind.modality} operators")
        return value

    @field_validator("operators")
    @classmethod
    def _no_duplicates(cls, value: list[OperatorChoice]) -> list[OperatorChoice]:
        """The same operator with the same config, or at a severity an earlier entry has, would run
        the same mutants twice: refused, naming the operator and the entries."""
        seen: dict[tuple[str, str], int] = {}
        for index, choice in enumerate(value):
            if choice.config is not None:
                from lidarfuzz.operators import get

                setting = get(choice.name)(**choice.config).config.model_dump(mode="json")
                keys = [(choice.name, "config " + json.dumps(setting, sort_keys=True))]
            else:
                keys = [(choice.name, f"severity {severity}") for severity in choice.severities]
            for key in keys:
                if key in seen:
                    what = "with this config" if choice.config is not None else f"at {key[1]}"
                    raise FieldError((index,), f"{choice.name} {what} is in entry {seen[key]} already: a "
                                               f"duplicate configuration runs the same mutants twice")
                seen[key] = index
        return value

    @model_validator(mode="after")
    def _kind(self) -> CampaignSpec:
        task_kind(self.kind).implementation().check_spec(self)  # e.g. a search section it cannot use
        return self

    @field_validator("relations")
    @classmethod
    def _relations(cls, value: Literal["auto"] | list[str | RelationChoice]) -> Any:
        if value == "auto":
            return value
        from lidarfuzz.oracles.relations import get

        try:
            return [get(item).name if isinstance(item, str) else item for item in value]
        except KeyError as exc:
            raise ValueError(str(exc)) from None


def parse_campaign(data: Any, source: str | PathLike[str] = "<campaign>") -> CampaignSpec:
    """Validate a mapping as a campaign; errors name the offending key."""
    if not isinstance(data, dict):
        raise DataFormatError(source, "a campaign must be a mapping with keys dataset, sut, operators, …")
    with reading(source, "read the campaign"):  # what pydantic's validators do not turn into errors
        try:
            return CampaignSpec.model_validate(data)
        except ValidationError as exc:
            raise _named(source, exc) from None


def _named(source: str | PathLike[str], exc: ValidationError) -> DataFormatError:
    """The first error as a DataFormatError naming its whole key path: a :class:`FieldError`'s
    path below the key pydantic reports is added (``operators.0.config.share_range.1``)."""
    first = exc.errors()[0]
    problem = (first.get("ctx") or {}).get("error")
    if not isinstance(problem, FieldError):
        return validation_error(source, exc)
    where = ".".join(str(part) for part in (*first["loc"], *problem.loc))
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    return DataFormatError(source, f"{problem.message}{more}", field=where)


def load_campaign(path: str | PathLike[str]) -> CampaignSpec:
    """Read a campaign file (YAML or JSON)."""
    path = Path(path)
    return parse_campaign(load_structured(path, "a campaign file"), path)
