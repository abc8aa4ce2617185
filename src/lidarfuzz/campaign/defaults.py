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
faults (fog, beam_missing). Left out: operators whose harmless range is empty or too narrow to
check a relation on (gaussian_noise_addition, motion_distortion, cross_sensor, object_scale), and
object-level edits that need labelled objects (a default must run on any data set).
"""

from __future__ import annotations

import json
from typing import Any

DEFAULT_OPERATORS: tuple[str, ...] = (
    "rotate_z", "height_shift", "global_translate", "global_flip", "uniform_noise_addition", "outside_roi_scatter",
    "intensity_scaling", "intensity_quantisation", "intensity_units", "fog", "beam_missing",
)
DEFAULT_SEVERITIES: tuple[int, ...] = (1, 3, 5)


def default_operators() -> list[dict[str, Any]]:
    """The default set as a campaign's ``operators`` entries, each at the default severities that
    configure it differently (a mirror has one setting whatever the severity).

        >>> default_operators()[0]
        {'name': 'rotate_z', 'severities': [1, 3, 5]}
        >>> default_operators()[3]
        {'name': 'global_flip', 'severities': [1]}
    """
    from lidarfuzz.operators.registry import get

    choices = []
    for name in DEFAULT_OPERATORS:
        cls, seen, severities = get(name), set(), []
        for severity in DEFAULT_SEVERITIES:
            key = json.dumps(cls.at_severity(severity).spec(), sort_keys=True)
            if key not in seen:
                seen.add(key)
                severities.append(severity)
        choices.append({"name": name, "severities": severities})
    return choices


__all__ = ["DEFAULT_OPERATORS", "DEFAULT_SEVERITIES", "default_operators"]
