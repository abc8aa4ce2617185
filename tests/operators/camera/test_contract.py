"""The operator contract for every registered camera operator: identity at severity 0, seeded
determinism, purity, replay from params and from a spec, composition, the harmless severities."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarfuzz.operators import Compose, Relation, Target, available, from_spec, generator, get
from lidarfuzz.scene.image import ImageSample

CAMERA = sorted(name for name, cls in available().items() if cls.modality == "camera")
NINE = ["image_blur", "image_brightness", "image_contrast", "image_fog", "image_rain", "image_rotation",
        "image_scale", "image_shear", "image_translation"]


def rng(trial: int = 0) -> np.random.Generator:
    return generator(campaign_seed=7, frame_id="000000", operator_index=0, trial=trial)


@pytest.fixture(scope="module")
def frame() -> ImageSample:
    """A 48×64 frame with texture, a depth map (road below, sky above) and a camera matrix."""
    noise = np.random.default_rng(0).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = np.full((48, 64), np.inf, np.float32)
    depth[24:] = np.linspace(40.0, 4.0, 24, dtype=np.float32)[:, None]
    k = np.array([[50.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]])
    return ImageSample(noise, frame_id="000000", steering=-0.05, depth=depth, intrinsics=k, timestamp=1.5,
                       metadata={"source": "test"})


def test_the_nine_are_registered_as_camera_operators_on_images():
    assert CAMERA == NINE
    for name in NINE:
        cls = available()[name]
        assert cls.targets == frozenset({Target.IMAGE}) and cls.relation is Relation.INVARIANT
        assert cls.harmless_because and sorted(cls.SEVERITIES) == [1, 2, 3, 4, 5]
    assert get("brightness") is available()["image_brightness"] and get("fog").modality == "lidar"


@pytest.mark.parametrize("name", CAMERA)
def test_severity_zero_is_the_identity(name, frame):
    mutant, params = available()[name].at_severity(0)(frame, rng())
    assert params.is_identity() and mutant == frame


@pytest.mark.parametrize("severity", [1, 3, 5])
@pytest.mark.parametrize("name", CAMERA)
def test_same_seed_same_image_and_input_untouched(name, severity, frame):
    before = (frame.image.copy(), frame.depth.copy(), frame.intrinsics.copy())
    op = available()[name].at_severity(severity)
    first, p1 = op(frame, rng(0))
    again, p2 = op(frame, rng(0))
    assert p1 == p2 and first == again
    assert not np.array_equal(first.image, frame.image)
    assert np.array_equal(frame.image, before[0]) and np.array_equal(frame.depth, before[1])
    assert np.array_equal(frame.intrinsics, before[2])
    assert first.image.dtype == np.uint8 and first.image.shape == frame.image.shape
    assert first.depth is not None and first.depth.shape == frame.depth.shape
    assert (first.frame_id, first.steering, first.timestamp, first.metadata) == \
        (frame.frame_id, frame.steering, frame.timestamp, frame.metadata)


@pytest.mark.parametrize("name", CAMERA)
def test_other_seeds_draw_other_params(name, frame):
    op = available()[name].at_severity(3)
    drawn = {json.dumps(op.sample(rng(trial), frame).model_dump(), sort_keys=True) for trial in range(6)}
    assert len(drawn) > 1


@pytest.mark.parametrize("name", CAMERA)
def test_replay_from_stored_params_and_spec(name, frame):
    op = available()[name].at_severity(4)
    mutant, params = op(frame, rng(3))
    assert op.apply(frame, op.parse_params(params.model_dump())) == mutant
    rebuilt = from_spec(json.loads(json.dumps(op.spec())))
    replayed = rebuilt.apply(frame, rebuilt.parse_params(json.loads(params.model_dump_json())))
    assert rebuilt.config == op.config and replayed == mutant


@pytest.mark.parametrize("name", CAMERA)
def test_harmless_up_to_its_declared_severity(name):
    cls = available()[name]
    assert cls.at_severity(0).harmless()
    for severity in range(1, 6):
        assert cls.at_severity(severity).harmless() == (severity <= cls.harmless_up_to), severity


def test_a_photo_without_depth_or_k_goes_through_every_operator(frame):
    photo = ImageSample(frame.image, frame_id="p")
    for name in CAMERA:
        mutant, params = available()[name].at_severity(3)(photo, rng())
        assert mutant.depth is None and mutant.intrinsics is None
        assert available()[name]().apply(photo, params) == mutant


def test_camera_operators_compose_and_replay(frame):
    chain = Compose([get("image_brightness").at_severity(2), get("image_rotation").at_severity(1),
                     get("image_fog").at_severity(2)])
    mutant, params = chain(frame, rng())
    assert [step.operator for step in params.steps] == ["image_brightness", "image_rotation", "image_fog"]
    assert chain.apply(frame, chain.parse_params(params.model_dump())) == mutant
    rebuilt = from_spec(json.loads(json.dumps(chain.spec())))
    assert rebuilt.apply(frame, rebuilt.parse_params(json.loads(params.model_dump_json()))) == mutant
    # the composite's own steps, applied one by one, give the same picture
    step = frame
    for op, record in zip(chain.operators, params.steps, strict=True):
        step = op.apply(step, op.parse_params(record.params))
    assert step == mutant


def test_severities_cover_table_4s_values_two_by_two():
    # Table 4: brightness 10..100 step 10, contrast 1.2..3.0 step 0.2, translation 10..100, scale
    # 1.5..6 step 0.5, shear −0.1..−1.0, rotation 3..30 step 3: severity s spans the (2s−1)-th and 2s-th
    fields = {"image_brightness": ("bias_range", [(10, 20), (30, 40), (50, 60), (70, 80), (90, 100)]),
              "image_contrast": ("gain_range", [(1.2, 1.4), (1.6, 1.8), (2.0, 2.2), (2.4, 2.6), (2.8, 3.0)]),
              "image_translation": ("tx_range", [(10, 20), (30, 40), (50, 60), (70, 80), (90, 100)]),
              "image_scale": ("factor_range", [(1.5, 2), (2.5, 3), (3.5, 4), (4.5, 5), (5.5, 6)]),
              "image_shear": ("sx_range", [(-0.2, -0.1), (-0.4, -0.3), (-0.6, -0.5), (-0.8, -0.7), (-1.0, -0.9)]),
              "image_rotation": ("angle_range", [(3, 6), (9, 12), (15, 18), (21, 24), (27, 30)])}
    for name, (field, expected) in fields.items():
        got = [getattr(get(name).at_severity(s).config, field) for s in range(1, 6)]
        assert np.allclose(got, expected), name
    blur = [get("image_blur").at_severity(s).config.filters for s in range(1, 6)]
    assert sorted(f for pair in blur for f in pair) == sorted(
        ["averaging:3", "averaging:4", "averaging:5", "averaging:6", "gaussian:3", "gaussian:5", "gaussian:7",
         "median:3", "median:5", "bilateral:9"])
