"""DeepTest's Algorithm 1 over image transformations: the evaluator and the search for steering systems.

The search itself is :class:`~lidarfuzz.search.algorithms.GuidedSearch` (a stack of seed images,
a queue of the transformations that raised coverage, two random transformations with random
parameters per try, a test kept when it raises neuron coverage); this module supplies what
differs for a camera frame:

* :class:`ImageSearchEvaluator` — an image keeps its label through any chain (DeepTest's
  assumption: a transformation at these parameters does not change the correct steering), so
  every test is valid and is judged by DeepTest's Eq. 2 against the data set's ``MSE_orig``
  (:class:`~lidarfuzz.oracles.relations.steering.DeepTestSteering`); a chain is a composite
  transformation, which the paper never filters by Eq. 3 (``filtered: 0``).
* :class:`ImageGuidedSearch` — draws each transformation's severity only up to the strongest at
  which it is meant to be harmless (its ``harmless_up_to``; transformations harmless at none are
  refused from the pool), so that a violation is one a correct system should not show.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from lidarfuzz.operators.registry import get
from lidarfuzz.search.algorithms import GuidedSearch, SearchConfig
from lidarfuzz.search.evaluate import ChainStep, Evaluation, SearchEvaluator


class ImageSearchEvaluator(SearchEvaluator):
    """Tests of image chains on a steering system with its neuron-coverage hooks.

    Args:
        dataset: An image data set (``load(frame_id)`` gives an :class:`~lidarfuzz.scene.image.ImageSample`).
        sut: A loaded steering system exposing its ``torch.nn.Module`` as ``module``.
        relations: Relation objects (``deeptest_steering``).
        recorder: An :class:`~lidarfuzz.coverage.ActivationRecorder` on the system's module.
        mse_orig: The system's MSE over the original data set (Eq. 2's reference).
    """

    def __init__(self, dataset: Any, sut: Any, relations: Sequence[Any], recorder: Any, *, mse_orig: float,
                 cache: int = 64) -> None:
        super().__init__(dataset, sut, relations, recorder, cache=cache)
        self.reference = {"mse_orig": float(mse_orig), "filtered": 0.0}

    def check_validity(self, source: Evaluation, evaluation: Evaluation) -> None:
        """Every image test is valid: the label is kept (DeepTest's premise; severities are capped
        at the harmless ones by :class:`ImageGuidedSearch`)."""


class ImageGuidedSearch(GuidedSearch):
    """Algorithm 1 with each transformation's parameters drawn among its harmless severities."""

    def __init__(self, config: SearchConfig, seeds: Sequence[str], criteria: Sequence[Any], seed: int) -> None:
        unjudged = [name for name in config.operators if get(name).harmless_up_to < 1]
        if unjudged:
            raise ValueError(f"operators {unjudged} are meant to be harmless at no severity, so no test of theirs "
                             "could be judged by Eq. 2; leave them out of the search's pool")
        super().__init__(config, seeds, criteria, seed)

    def random_step(self, rng: np.random.Generator, name: str | None = None) -> tuple[ChainStep, int]:
        name = name or str(rng.choice(list(self.config.operators)))
        cls = get(name)
        top = min(self.config.max_severity, cls.harmless_up_to)
        severity = int(rng.integers(1, top + 1))
        return ChainStep(cls.at_severity(severity).spec()), severity


__all__ = ["ImageGuidedSearch", "ImageSearchEvaluator"]
