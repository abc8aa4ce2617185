"""The bug zoo: each variant's documented operator makes its output differ from the correct
pipeline's on a simulator frame, and the documented relation sees more violations."""

from __future__ import annotations

import pytest

from lidarfuzz.operators import available, generator
from lidarfuzz.oracles.matching import match_boxes
from lidarfuzz.oracles.relations import Pair, from_spec
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.dataset import GenerationConfig, render_frames
from lidarfuzz.suts.bugzoo import BUGS, BuggyPipeline
from lidarfuzz.suts.classic import ClassicPipeline
from lidarfuzz.suts.registry import available as registered_suts

# frame of the simulator (seed 0, HDL-64E) on which each bug is shown; True where the bug
# also stays hidden on that frame's original
SHOWN_ON: dict[str, tuple[int, bool]] = {
    "classic-bug-intensity-norm": (2, True),
    "classic-bug-point-cap": (0, True),
    "classic-bug-dense-cell": (0, True),
    "classic-bug-yaw-wrap": (2, True),
    "classic-bug-roi-cache": (0, True),
    "classic-bug-fixed-ground": (4, True),
    "classic-bug-sign-filter": (0, False),
    "classic-bug-forward-ground": (3, True),
}


@pytest.fixture(scope="module")
def frames() -> list[Scene]:
    return list(render_frames(GenerationConfig(frames=5, seed=0)))


def same(a: Boxes3D, b: Boxes3D) -> bool:
    return len(a) == len(b) and (len(a) == 0 or len(match_boxes(a, b, min_iou=0.8).pairs) == len(a))


def test_the_zoo_is_registered_and_documented() -> None:
    assert len(BUGS) >= 8 and set(SHOWN_ON) == {b.name for b in BUGS}
    for bug in BUGS:
        assert registered_suts()[bug.name] is bug
        assert bug.bug and bug.hidden and bug.reveal.why
        assert bug.reveal.operator in available()
        assert bug.reveal.relation in ("preservation", "equivariance", "invariance", "gt_recall")
        assert bug().fingerprint() != ClassicPipeline().fingerprint()


@pytest.mark.parametrize("bug", BUGS, ids=lambda b: b.name)
def test_the_documented_operator_reveals_the_bug(bug: type[BuggyPipeline], frames: list[Scene]) -> None:
    index, hidden = SHOWN_ON[bug.name]
    source = frames[index]
    correct, buggy = ClassicPipeline(), bug()
    source_correct, source_buggy = correct.detect(source), buggy.detect(source)
    if hidden:
        assert same(source_correct, source_buggy), "the bug should stay hidden on this original"
    op = available()[bug.reveal.operator].at_severity(bug.reveal.severity)
    mutant, params = op(source, generator(0, source.frame_id, 0, 0))
    follow_correct, follow_buggy = correct.detect(mutant), buggy.detect(mutant)
    assert not same(follow_correct, follow_buggy), "the operator should make the bug show"
    relation = from_spec(bug.reveal.relation)
    t = op.transform(params)
    flagged_bug = relation(Pair(source, mutant, source_buggy, follow_buggy, op.relation, transform=t))
    flagged_ok = relation(Pair(source, mutant, source_correct, follow_correct, op.relation, transform=t))
    assert len(flagged_bug.violations) >= len(flagged_ok.violations)
