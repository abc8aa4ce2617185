"""The default operator set: what ``lidarfuzz demo``, a campaign's ``operators: auto`` and
``lidarfuzz run --op auto`` run.

Chosen by floor. At its harmless severities, each operator here gives the correct classic pipeline
no relation violation on the built-in world (``benchmarks/false_alarms.py``), so a violation there
means something. Each still reaches the severities where it degrades, where AP loss and a
reference system's objects lost tell a bug from the mutation's cost. Between them they cover the
faults real pipelines have: a frame turned, lifted, moved or mirrored (rotate_z, height_shift,
global_translate, global_flip); points added inside and outside the map's region of interest
(uniform_noise_addition, outside_roi_scatter); intensities rescaled, quantised or re-expressed in
other units (intensity_scaling, intensity_quantisation, intensity_units); weather and sensor
faults (fog, beam_missing); a sensor switched to dual return, up to nearly twice the points
(dual_return: not harmless at any severity, so only AP and a reference's objects lost judge it — the
way a limit sized for single-return data shows). Left out: operators whose harmless range is empty or too narrow to
check a relation on (gaussian_noise_addition, motion_distortion, cross_sensor, object_scale), and
object-level edits that need labelled objects (a default must run on any data set).
"""

from __future__ import annotations

import json
from typing import Any

DEFAULT_OPERATORS: tuple[str, ...] = (
    "rotate_z", "height_shift", "global_translate", "global_flip", "uniform_noise_addition", "outside_roi_scatter",
    "intensity_scaling", "intensity_quantisation", "intensity_units", "fog", "beam_missing", "dual_return",
)
DEFAULT_SEVERITIES: tuple[int, ...] = (1, 3, 5)


def distinct_severities(name: str, severities: tuple[int, ...] | list[int]) -> list[int]:
    """``severities`` of operator ``name`` less those configuring it as an earlier one does (a
    mirror has one setting whatever the severity).

        >>> distinct_severities("global_flip", [1, 3, 5]), distinct_severities("fog", [1, 3, 5])
        ([1], [1, 3, 5])
    """
    from lidarfuzz.operators.registry import get

    cls, seen, kept = get(name), set(), []
    for severity in severities:
        key = json.dumps(cls.at_severity(severity).spec(), sort_keys=True)
        if key not in seen:
            seen.add(key)
            kept.append(severity)
    return kept


def default_operators() -> list[dict[str, Any]]:
    """The default set as a campaign's ``operators`` entries, each at the default severities that
    configure it differently.

        >>> default_operators()[0]
        {'name': 'rotate_z', 'severities': [1, 3, 5]}
        >>> default_operators()[3]
        {'name': 'global_flip', 'severities': [1]}
    """
    return [{"name": name, "severities": distinct_severities(name, DEFAULT_SEVERITIES)} for name in DEFAULT_OPERATORS]


__all__ = ["DEFAULT_OPERATORS", "DEFAULT_SEVERITIES", "default_operators", "distinct_severities"]
