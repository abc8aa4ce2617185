"""The thesis's first experiment (Table 6-7), :mod:`lidarfuzz.campaign.ratings`: drawing pairs, keeping
verdicts, the tally and Fleiss' kappa — on a store whose task rows are written here by hand (ten
frames, four operators), so that every expected figure can be worked out on paper."""

from __future__ import annotations

from pathlib import Path

import pytest

from lidarfuzz.campaign.ratings import (
    THESIS_EXCLUDED,
    draw_pairs,
    fleiss_kappa,
    ratings_of,
    record_rating,
    tally,
)
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store import Store
from lidarfuzz.store.contracts import FailureRecord
from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.models import Dataset, FrameResult, Model, Subtask, Task

FRAMES = [f"{i:06d}" for i in range(10)]
# (name, severity); rotate_z is the thesis's RAR, left out of a draw unless named
OPERATORS = [("uniform_noise_addition", 1), ("uniform_point_deletion", 2), ("rotate_z", 1)]


def _task(store: Store, *, seed: int = 5) -> int:
    """A task with originals and OPERATORS on FRAMES; uniform_point_deletion failed (operator_error)
    on frame 000003, the system crashed on frame 000004's noise mutant (still a mutant to rate), and
    frame 000009 has no original result."""
    with store.session() as s:
        dataset = Dataset(name=f"d{seed}", path="/nowhere", format="kitti", frame_count=len(FRAMES))
        model = Model(name=f"m{seed}", spec="classic", fingerprint="f")
        s.add_all([dataset, model])
        s.flush()
        task = Task(dataset_id=dataset.id, model_id=model.id, seed=seed)
        s.add(task)
        s.flush()
        subs = [Subtask(task_id=task.id, operator_key="original", operator={}, name="original", severity=0)]
        subs += [Subtask(task_id=task.id, operator_key=f"{name}{sev}", operator={"name": name, "config": {}},
                         name=name, severity=sev) for name, sev in OPERATORS]
        s.add_all(subs)
        s.flush()
        for sub in subs:
            for frame in FRAMES:
                if sub.name == "original" and frame == "000009":
                    continue
                failure = None
                if sub.name == "uniform_point_deletion" and frame == "000003":
                    failure = FailureRecord(kind="operator_error", message="boom")
                if sub.name == "uniform_noise_addition" and frame == "000004":
                    failure = FailureRecord(kind="crash", message="segfault")
                s.add(FrameResult(subtask_id=sub.id, frame_id=frame, trial=0, params={}, failure=failure))
        s.commit()
        return task.id


@pytest.fixture
def store(tmp_path: Path) -> Store:
    return Store(tmp_path / "ws")


def test_a_draw_takes_the_same_frames_for_every_operator_and_leaves_the_thesis_exclusions_out(store: Store) -> None:
    task = _task(store)
    draw = draw_pairs(store, task, per_operator=4)
    assert draw.seed == 5  # the task's seed by default
    assert draw.strata == ("uniform_noise_addition@1", "uniform_point_deletion@2")
    assert draw.excluded == ("rotate_z@1",)
    assert "RAR" in THESIS_EXCLUDED
    assert len(draw.frames) == 4 and len(draw.pairs) == 8
    # 000003 (no deletion mutant) and 000009 (no original) cannot be drawn; a crash on 000004 can
    assert not {"000003", "000009"} & set(draw.frames)
    by_operator = {op: [p.frame_id for p in draw.pairs if p.operator == op] for op, _ in OPERATORS[:2]}
    assert by_operator["uniform_noise_addition"] == by_operator["uniform_point_deletion"] == list(draw.frames)
    assert len({p.id for p in draw.pairs}) == 8


def test_the_same_seed_gives_the_same_draw_and_other_seeds_other_ones(store: Store) -> None:
    task = _task(store)
    first = draw_pairs(store, task, per_operator=4, seed=11)
    assert draw_pairs(store, task, per_operator=4, seed=11) == first
    # 8 usable frames choose 4: 70 subsets; twenty seeds all drawing one subset cannot be chance
    assert len({draw_pairs(store, task, per_operator=4, seed=s).frames for s in range(20)}) > 1


def test_asking_for_more_frames_than_there_are_takes_them_all(store: Store) -> None:
    task = _task(store)
    draw = draw_pairs(store, task)  # the thesis's 100 per operator; 8 frames are usable
    assert draw.per_operator == 100
    assert draw.frames == ("000000", "000001", "000002", "000004", "000005", "000006", "000007", "000008")


def test_operators_by_name_or_alias_and_unknown_ones_refused(store: Store) -> None:
    task = _task(store)
    draw = draw_pairs(store, task, per_operator=2, operators=["RAR", "upd"])
    assert draw.strata == ("uniform_point_deletion@2", "rotate_z@1")
    assert draw.excluded == ("uniform_noise_addition@1",)
    with pytest.raises(LidarfuzzError, match=r"^operators: the task has no operator 'fog'"):
        draw_pairs(store, task, operators=["fog"])
    with pytest.raises(LidarfuzzError, match=r"^per_operator: at least 1"):
        draw_pairs(store, task, per_operator=0)


def test_each_rater_has_an_order_of_their_own_kept_across_visits(store: Store) -> None:
    task = _task(store)
    draw = draw_pairs(store, task, per_operator=4)
    ana = draw.for_rater("ana")
    assert sorted(p.id for p in ana) == sorted(p.id for p in draw.pairs)
    assert draw.for_rater("  ana ") == ana  # trimmed, as the verdicts are kept
    assert [p.id for p in draw.for_rater("ben")] != [p.id for p in ana]
    with pytest.raises(LidarfuzzError, match=r"^rater: a name is needed"):
        draw.for_rater(" ")


def test_rating_again_replaces_the_verdict_and_keeps_the_first_time(store: Store) -> None:
    task = _task(store)
    pair = draw_pairs(store, task, per_operator=1).pairs[0]
    first = record_rating(store, task, pair.id, "ana", "Same")
    assert first.verdict == "same" and first.first_rated_at == first.rated_at
    second = record_rating(store, task, pair.id, "ana", "different")
    assert second.verdict == "different"
    assert second.first_rated_at == first.first_rated_at and second.rated_at > first.rated_at
    assert [(v.pair_id, v.verdict) for v in ratings_of(store, task, "ana")] == [(pair.id, "different")]
    with pytest.raises(LidarfuzzError, match=r"^verdict: expected one of same, similar, different, got 'maybe'"):
        record_rating(store, task, pair.id, "ana", "maybe")


def test_a_pair_must_be_a_mutant_of_the_task(store: Store) -> None:
    task, other = _task(store, seed=5), _task(store, seed=6)
    pair = draw_pairs(store, task, per_operator=1).pairs[0]
    with pytest.raises(NotFoundError, match=f"task {other} has no pair {pair.id}"):
        record_rating(store, other, pair.id, "ana", "same")
    with store.session() as s:  # an original is no pair
        original = s.query(FrameResult.id).join(Subtask).filter(Subtask.task_id == task,
                                                                Subtask.name == "original").first()[0]
    with pytest.raises(NotFoundError):
        record_rating(store, task, original, "ana", "same")


def test_the_tally_sums_verdicts_over_raters_per_operator(store: Store) -> None:
    task = _task(store)
    draw = draw_pairs(store, task, per_operator=2)
    noise = [p for p in draw.pairs if p.operator == "uniform_noise_addition"]
    deletion = [p for p in draw.pairs if p.operator == "uniform_point_deletion"]
    verdicts = {(noise[0].id, "ana"): "same", (noise[0].id, "ben"): "same", (noise[0].id, "cy"): "similar",
                (noise[1].id, "ana"): "same", (noise[1].id, "ben"): "different", (noise[1].id, "cy"): "different",
                (deletion[0].id, "ana"): "same"}
    for (pair_id, rater), verdict in verdicts.items():
        record_rating(store, task, pair_id, rater, verdict)
    table = tally(store, task)
    assert table.raters == ("ana", "ben", "cy")
    row_noise, row_deletion = table.rows
    # noise: same 3, similar 1, different 2 of 6 verdicts on 2 pairs by 3 raters
    assert (row_noise.label, row_noise.alias) == ("uniform_noise_addition@1", "UNA")
    assert (row_noise.same, row_noise.similar, row_noise.different, row_noise.total) == (3, 1, 2, 6)
    assert row_noise.share("same") == pytest.approx(0.5) and row_noise.same_or_similar_share == pytest.approx(4 / 6)
    assert (row_noise.pairs, row_noise.raters) == (2, 3)
    # Fleiss by hand: pair 1 [2, 1, 0]: P = (4 + 1 - 3) / (3 * 2) = 1/3; pair 2 [1, 0, 2]: P = (1 + 4 - 3) / 6 = 1/3;
    # P̄ = 1/3; shares (3/6, 1/6, 2/6): P̄e = 9/36 + 1/36 + 4/36 = 7/18; κ = (1/3 - 7/18) / (1 - 7/18) = -1/11
    assert row_noise.kappa == pytest.approx(-1 / 11)
    # deletion: one verdict by one rater; no pair with two raters, so no kappa
    assert (row_deletion.same, row_deletion.total, row_deletion.pairs, row_deletion.raters) == (1, 1, 1, 1)
    assert row_deletion.kappa is None
    # the total row: 7 verdicts; kappa from the two pairs rated by several (the same -1/11)
    assert (table.total.same, table.total.similar, table.total.different) == (4, 1, 2)
    assert table.total.kappa == pytest.approx(-1 / 11)


def test_fleiss_kappa_on_wikipedias_worked_example() -> None:
    # Fleiss' kappa, Wikipedia's example: 10 subjects, 14 raters, 5 categories; P̄ = 0.378, P̄e = 0.213, κ = 0.210
    table = [[0, 0, 0, 0, 14], [0, 2, 6, 4, 2], [0, 0, 3, 5, 6], [0, 3, 9, 2, 0], [2, 2, 8, 1, 1],
             [7, 7, 0, 0, 0], [3, 2, 6, 3, 0], [2, 5, 3, 2, 2], [6, 5, 2, 1, 0], [0, 2, 2, 3, 7]]
    assert fleiss_kappa(table) == pytest.approx(0.210, abs=5e-4)


def test_fleiss_kappa_edges() -> None:
    # perfect agreement across categories: every P_i = 1, P̄e = 1/2 -> κ = 1
    assert fleiss_kappa([[3, 0, 0], [0, 3, 0]]) == pytest.approx(1.0)
    # every verdict in one category: P̄e = 1, undefined
    assert fleiss_kappa([[2, 0, 0], [3, 0, 0]]) is None
    # no item with two raters
    assert fleiss_kappa([[1, 0, 0], [0, 0, 1]]) is None
    assert fleiss_kappa([]) is None


def test_deleting_the_task_deletes_its_verdicts(store: Store) -> None:
    from lidarfuzz.campaign.tasks import delete_task
    from lidarfuzz.store.models import Rating

    task, other = _task(store, seed=5), _task(store, seed=6)
    record_rating(store, task, draw_pairs(store, task, per_operator=1).pairs[0].id, "ana", "same")
    record_rating(store, other, draw_pairs(store, other, per_operator=1).pairs[0].id, "ana", "same")
    delete_task(store, task)
    with store.session() as s:
        assert [r.task_id for r in s.query(Rating).all()] == [other]


def test_the_camera_image_of_a_pair_is_the_frames_image_2_file(store: Store, tmp_path: Path) -> None:
    from lidarfuzz.report.ratings import camera_image

    task = _task(store)
    pair = draw_pairs(store, task, per_operator=1).pairs[0]
    assert camera_image(store, task, pair.id) is None  # /nowhere: no image_2/
    folder = tmp_path / "kitti" / "image_2"
    folder.mkdir(parents=True)
    (folder / f"{pair.frame_id}.jpg").write_bytes(b"\xff\xd8jpeg")
    with store.session() as s:
        dataset = s.get(Task, task).dataset
        dataset.path = str(tmp_path / "kitti")
        s.commit()
    assert camera_image(store, task, pair.id) == (b"\xff\xd8jpeg", "image/jpeg")
