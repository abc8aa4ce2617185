"""A system's fingerprint covers its code: a Python system whose module changed, or a program
whose script changed, has another fingerprint with the same name, version and configuration."""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata
import shutil
import sys
from pathlib import Path

import numpy as np

from lidarfuzz.suts.classic import ClassicPipeline
from lidarfuzz.suts.code import program_code, python_code
from lidarfuzz.suts.registry import create

SYSTEM = '''
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.suts.base import SystemUnderTest


class Det(SystemUnderTest):
    name = "det"
    version = "1"

    def detect(self, sample):
        return Boxes3D.empty()  # {variant}


def detector(points):
    return Boxes3D.empty()  # {variant}
'''


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_module(folder: Path, name: str, variant: str) -> None:
    (folder / f"{name}.py").write_text(SYSTEM.format(variant=variant))


def test_a_python_system_whose_module_changed_has_another_fingerprint(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(tmp_path))
    write_module(tmp_path, "fp_changing_module", "first")
    module = importlib.import_module("fp_changing_module")
    try:
        before, adapter_before = create("fp_changing_module:Det"), create("fp_changing_module:detector")
        identity = (before.name, before.version, dict(before.config()))
        fingerprints = before.fingerprint(), adapter_before.fingerprint()
        # the module's file, keyed by module name: its bytes' SHA-256, nothing else of the user's
        assert before.code()["fp_changing_module"] == sha256(tmp_path / "fp_changing_module.py")
        write_module(tmp_path, "fp_changing_module", "first")  # the same bytes again: the same system
        assert (create("fp_changing_module:Det").fingerprint(), adapter_before.fingerprint()) == fingerprints
        write_module(tmp_path, "fp_changing_module", "second, with other code")
        importlib.reload(module)
        after, adapter_after = create("fp_changing_module:Det"), create("fp_changing_module:detector")
        assert (after.name, after.version, dict(after.config())) == identity
        assert after.fingerprint() != fingerprints[0]
        assert adapter_after.fingerprint() != fingerprints[1]  # a module:callable adapter: the callable's module
    finally:
        sys.modules.pop("fp_changing_module", None)


def test_lidarfuzz_systems_hash_their_package_and_third_party_code_its_version() -> None:
    root = Path(importlib.import_module("lidarfuzz").__file__).parent
    code = python_code([ClassicPipeline])
    # the classic pipeline's package and the SUT package around it (the contract, the bug zoo)
    for name in ("suts/classic/pipeline.py", "suts/classic/ground.py", "suts/base.py", "suts/bugzoo.py"):
        assert code[f"lidarfuzz/{name}"] == sha256(root / name)
    assert not any(key.startswith("lidarfuzz/scene/") for key in code)  # only the SUT package
    assert python_code([np.ndarray]) == {"dist:numpy": importlib.metadata.version("numpy")}
    assert python_code([dict, Path]) == {}  # built-ins and the standard library: nothing


def test_a_program_whose_script_changed_has_another_fingerprint(tmp_path: Path) -> None:
    script = tmp_path / "detector.py"
    script.write_text("print('{}')\n")
    worker = create(f"worker:{sys.executable} -u {script}")
    one_shot = create(f"subprocess:{sys.executable} {script} {{points}} {{output}}")
    before = worker.fingerprint(), one_shot.fingerprint()
    code = worker.code()
    assert code[f"program:{sys.executable}"] == sha256(Path(sys.executable).resolve())
    assert code[f"file:{script}"] == sha256(script) and "file:-u" not in code
    script.write_text("print('{\"detections\": []}')\n")
    after = worker.fingerprint(), one_shot.fingerprint()
    assert after[0] != before[0] and after[1] != before[1]
    assert worker.config() == create(f"worker:{sys.executable} -u {script}").config()


def test_a_command_name_is_resolved_on_the_path() -> None:
    python = Path(sys.executable).name
    found = shutil.which(python)
    assert found is not None
    assert program_code([python, "{points}"]) == {f"program:{python}": sha256(Path(found))}
    assert program_code(["no-such-program-lidarfuzz"]) == {"program:no-such-program-lidarfuzz": "not found"}
