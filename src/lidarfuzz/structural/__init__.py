"""Structural testing with logs (Neves, Delamaro & Masiero): code coverage of a system under
test replayed over ordered logs of frames, segments, discriminatory-segment heuristics and
generated logs.

Modules: :mod:`~lidarfuzz.structural.requirements` (the requirements every coverage producer
reports and the paper's coverage formulas); code coverage: :mod:`~lidarfuzz.structural.targets`
(what to cover), :mod:`~lidarfuzz.structural.python_coverage` (control-flow graphs from
coverage.py's arcs, measured per call), :mod:`~lidarfuzz.structural.gcov` (compiled programs,
gcov data via gcovr) and :mod:`~lidarfuzz.structural.views` (tables, annotated source, graphs,
comparisons); logs: :mod:`~lidarfuzz.structural.logs` (data sets in replay order),
:mod:`~lidarfuzz.structural.segments`, :mod:`~lidarfuzz.structural.heuristics` (discriminatory
segments), :mod:`~lidarfuzz.structural.log_coverage` (a log replayed under coverage, two logs
compared), :mod:`~lidarfuzz.structural.generate` (generated logs),
:mod:`~lidarfuzz.structural.search` (a search for logs that reach uncovered code) and
:mod:`~lidarfuzz.structural.stored` (the meta-model in the store).
"""
