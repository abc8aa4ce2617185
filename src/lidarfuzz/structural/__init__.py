"""Structural testing with logs (Neves, Delamaro & Masiero): code coverage of a system under
test replayed over ordered logs of frames, segments, discriminatory-segment heuristics and
generated logs.

Modules: :mod:`~lidarfuzz.structural.requirements` (the requirements every coverage producer
reports and the paper's coverage formulas).
"""
