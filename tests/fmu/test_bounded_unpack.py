"""An FMU or SSP that would unpack into too much is refused before anything is written."""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from pathlib import Path

import pytest

from cosimstep.adapters.fmu_base import check_fmu
from cosimstep.errors import ConfigurationError

MIB = 1024**2


def _bomb(source: Path, target: Path, member: str, size: int) -> Path:
    shutil.copy(source, target)
    with zipfile.ZipFile(target, "a", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(member, b"\0" * size)  # 20 MiB of zeros: about 20 KiB compressed
    return target


def _unpacked() -> set[Path]:
    return set(Path(tempfile.gettempdir()).glob("cosimstep-*"))


def test_an_fmu_above_the_limit_or_the_ratio_is_refused_unread(bar_fmus, tmp_path,
                                                                 monkeypatch):
    monkeypatch.setenv("COSIMSTEP_UNPACK_LIMIT", str(10 * MIB))
    bomb = _bomb(bar_fmus[1], tmp_path / "bomb.fmu", "resources/zeros.bin", 20 * MIB)
    before = _unpacked()
    with pytest.raises(ValueError) as info:
        check_fmu(bomb)
    message = str(info.value)
    assert "above the limit of 10.0 MiB" in message  # both reasons, at once
    assert "member 'resources/zeros.bin' unpacks 20.0 MiB" in message and "zip bomb" in message
    assert _unpacked() == before  # nothing was written
    # sources/ is never unpacked, so it does not count against the limit
    docs = _bomb(bar_fmus[1], tmp_path / "docs.fmu", "sources/zeros.c", 20 * MIB)
    assert check_fmu(docs).modelName


def test_an_ssp_above_the_limit_is_a_configuration_error(bar_fmus, tmp_path, monkeypatch):
    from cosimstep.ssp import load_ssp

    monkeypatch.setenv("COSIMSTEP_UNPACK_LIMIT", str(10 * MIB))
    ssp = tmp_path / "bomb.ssp"
    with zipfile.ZipFile(ssp, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("SystemStructure.ssd", "<x/>")
        zf.writestr("resources/zeros.bin", b"\0" * (20 * MIB))
    before = _unpacked()
    with pytest.raises(ConfigurationError) as info:
        load_ssp(ssp)
    text = str(info.value)
    assert "above the limit" in text and "zip bomb" in text
    assert _unpacked() == before


def test_instances_of_one_fmu_share_one_unpacked_folder(bar_fmus, tmp_path):
    import numpy as np

    from cosimstep.adapters.fmu import FmuSubModel

    a = FmuSubModel(bar_fmus[1], instance_name="a")
    b = FmuSubModel(bar_fmus[1], instance_name="b")
    a.initialize(0.0)
    b.initialize(0.0)
    try:
        assert a._unzipped == b._unzipped and a._unzipped.is_dir()
        for m in (a, b):  # independent instances all the same
            m.set_inputs(np.array([0.1, 0.0]))
        a.do_step(0.0, 0.01)
        assert not np.array_equal(a.get_outputs(), b.get_outputs())
        b.do_step(0.0, 0.01)
        assert np.array_equal(a.get_outputs(), b.get_outputs())
    finally:
        folder, library = a._unzipped, a._fmu.dll._name
        a.terminate()
        assert folder.is_dir()  # b still uses it
        b.terminate()
    assert folder.is_dir() and _loaded(library)  # kept: a later instance finds both
    copy = shutil.copy(bar_fmus[1], tmp_path / "elsewhere.fmu")  # same content, other path
    for model in (FmuSubModel(bar_fmus[1], instance_name="c"), FmuSubModel(copy)):
        model.initialize(0.0)
        try:
            assert model._unzipped == folder
        finally:
            model.terminate()
    shutil.rmtree(folder)  # a cleaner of the temporary directory
    model = FmuSubModel(bar_fmus[1])
    model.initialize(0.0)  # unpacked again where the loaded library expects it
    try:
        assert model._unzipped == folder and (folder / ".cosimstep-owner").is_file()
        model.do_step(0.0, 0.01)
    finally:
        model.terminate()


def _loaded(library: str) -> bool:
    """Whether the shared library at ``library`` is mapped in this process (dlopen with
    RTLD_NOLOAD fails for one that is not)."""
    import ctypes
    import os

    try:
        ctypes.CDLL(library, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)
    except OSError:
        return False
    return True


def test_an_fmu_that_runs_once_per_process_is_refused_twice_and_unloaded(bar_fmus, tmp_path):
    """canBeInstantiatedOnlyOncePerProcess: a second live instance is refused with the reason;
    the library goes with the instance, so a later one starts from a fresh library."""
    from cosimstep.adapters.fmu import FmuSubModel
    from cosimstep.adapters.fmu_base import FmuError

    once = tmp_path / "once.fmu"
    with zipfile.ZipFile(bar_fmus[1]) as src, zipfile.ZipFile(once, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'canBeInstantiatedOnlyOncePerProcess="false"',
                                    b'canBeInstantiatedOnlyOncePerProcess="true"')
            dst.writestr(item, data)
    first = FmuSubModel(once, instance_name="first")
    first.initialize(0.0)
    folder, library = first._unzipped, first._fmu.dll._name
    try:
        with pytest.raises(FmuError, match=r"only once per process.*'first' is alive"):
            FmuSubModel(once, instance_name="second").initialize(0.0)
    finally:
        first.terminate()
    assert not folder.exists() and not _loaded(library)
    again = FmuSubModel(once, instance_name="again")
    again.initialize(0.0)
    again.terminate()

    from click.testing import CliRunner

    from cosimstep.cli import main

    system = tmp_path / "two.toml"  # found before the run: exit 2, the reason and the fix
    system.write_text(f'until = 0.1\n[models.a]\ntype = "fmu"\npath = "{once.name}"\n'
                      f'[models.b]\ntype = "fmu"\npath = "{once.name}"\n'
                      '[controller]\nname = "fixed"\nstep = 0.01\n')
    res = CliRunner().invoke(main, ["run", str(system), "--no-store"])
    assert res.exit_code == 2 and "a, b are instances of one FMU" in res.output \
        and "separate processes" in res.output and "Traceback" not in res.output


def test_a_loaded_library_and_its_folder_go_when_the_process_exits(bar_fmus):
    """The library is never unloaded (an FMU's state beyond its instances need not survive
    being loaded again: docs/reliability.md); its folder goes at exit."""
    import subprocess
    import sys

    script = ("import sys\n"
              "from cosimstep.adapters.fmu import FmuSubModel\n"
              "for name in ('a', 'b'):\n"
              "    m = FmuSubModel(sys.argv[1], instance_name=name)\n"
              "    m.initialize(0.0)\n"
              "    m.do_step(0.0, 0.01)\n"
              "    folder = m._unzipped\n"
              "    m.terminate()\n"
              "print(folder, folder.is_dir())\n")
    done = subprocess.run([sys.executable, "-c", script, str(bar_fmus[1])],
                          capture_output=True, text=True, check=True, timeout=120)
    folder, existed = done.stdout.split()
    assert existed == "True" and not Path(folder).exists()


def test_folders_left_by_a_killed_process_are_swept(tmp_path):
    import os
    import socket
    import subprocess
    import sys

    from cosimstep.archive import OWNER_FILE, sweep

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    host = socket.gethostname()
    owners = {"cosimstep-gone-1": f"{host} {int(dead.stdout)}",  # its process has ended
              "cosimstep-live-1": f"{host} {os.getpid()}",  # this process
              "cosimstep-other-1": f"elsewhere {int(dead.stdout)}"}  # another machine's
    for name, owner in owners.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / OWNER_FILE).write_text(owner + "\n")
    (tmp_path / "cosimstep-unmarked").mkdir()  # not made by us: left alone
    assert sweep(tmp_path) == [tmp_path / "cosimstep-gone-1"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "cosimstep-live-1", "cosimstep-other-1", "cosimstep-unmarked"]
