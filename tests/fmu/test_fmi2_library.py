"""The FMI 2.0 loader behind FmuSubModel (Fmi2Slave) and the model-description check with cached
schemas: the same values as FMPy's FMU2Slave on the pendulum-bar FMU, checked statuses, refusal
of a library that lacks a function, a refused instantiation cleaned up, and schema validation
that refuses what FMPy's validating reader refuses."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import fmpy
import pytest
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

from cosimstep.adapters.fmi2_library import Fmi2Slave
from cosimstep.adapters.fmu import FmuError, FmuSubModel, check_fmu

from .test_adapter import _rewrite


def _open(cls: type, path: Path, folder: Path, callbacks) -> object:
    md = fmpy.read_model_description(str(path))
    fmpy.extract(str(path), unzipdir=str(folder))
    fmu = cls(guid=md.guid, unzipDirectory=str(folder),
              modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bar")
    fmu.instantiate(callbacks=callbacks)
    fmu.setupExperiment(startTime=0.0)
    fmu.setReal([4], [2.0])  # m1
    fmu.enterInitializationMode()
    fmu.setReal([2, 3], [-0.3, 0.0])
    fmu.exitInitializationMode()
    return fmu


def test_same_values_as_fmpy_and_checked_statuses(bar_fmus: dict[int, Path],
                                                   tmp_path: Path) -> None:
    callbacks = FmuSubModel(bar_fmus[1])._fmi2_callbacks()
    ours = _open(Fmi2Slave, bar_fmus[1], tmp_path / "ours", callbacks)
    theirs = _open(FMU2Slave, bar_fmus[1], tmp_path / "theirs", callbacks)
    try:
        for n in range(50):
            for fmu in (ours, theirs):
                fmu.setReal([2, 3], [-0.3 + 0.001 * n, 0.01])
                fmu.doStep(n * 0.01, 0.01)
            assert ours.getReal([0, 1, 2, 3]) == theirs.getReal([0, 1, 2, 3])
        state = ours.getFMUstate()
        before = ours.getReal([0, 1])
        ours.doStep(0.5, 0.01)
        ours.setFMUstate(state)
        ours.freeFMUstate(state)
        assert ours.getReal([0, 1]) == before
        with pytest.raises(FMICallException, match="fmi2DoStep failed with status 3"):
            ours.doStep(7.0, 0.01)  # not the FMU's time
        with pytest.raises(FMICallException, match="fmi2SetInteger"):
            ours.setInteger([0], [1])  # the FMU has no Integer variables
    finally:
        for fmu in (ours, theirs):
            fmu.terminate()
            fmu.freeInstance()


def test_library_without_a_required_function_is_refused(tmp_path: Path) -> None:
    binaries = tmp_path / "binaries" / fmpy.platform
    binaries.mkdir(parents=True)
    source = tmp_path / "partial.c"
    source.write_text("void *fmi2Instantiate(void) { return 0; }\n"
                      "int fmi2DoStep(void) { return 0; }\n")
    subprocess.run(["gcc", "-shared", "-fPIC", "-o",
                    str(binaries / f"partial{fmpy.sharedLibraryExtension}"), str(source)],
                   check=True)
    with pytest.raises(OSError, match=r"lacks fmi2FreeInstance, fmi2SetupExperiment, .*"
                                      r"fmi2SetBoolean \(an FMI 2.0 co-simulation"):
        Fmi2Slave(guid="x", modelIdentifier="partial", unzipDirectory=tmp_path)
    with pytest.raises(FileNotFoundError, match="cannot find the FMU's shared library"):
        Fmi2Slave(guid="x", modelIdentifier="absent", unzipDirectory=tmp_path)


def test_refused_instantiation_names_the_call_and_cleans_up(bar_fmus: dict[int, Path],
                                                            tmp_path: Path) -> None:
    wrong_guid = _rewrite(bar_fmus[1], tmp_path / "guid.fmu", md=lambda xml: re.sub(
        r'guid="[^"]*"', 'guid="{00000000-0000-0000-0000-000000000000}"', xml))
    model = FmuSubModel(wrong_guid, instance_name="upper")
    with pytest.raises(FmuError, match=r"FMU 'upper' .*fmi2Instantiate returned NULL.*FMU log: "
                                       r"\[error\] GUID .* does not match"):
        model.initialize(0.0)
    assert model._unzipped is None and model._fmu is None


def test_validation_refuses_what_fmpy_refuses(bar_fmus: dict[int, Path],
                                              tmp_path: Path) -> None:
    good = bar_fmus[1]
    bad_attribute = _rewrite(good, tmp_path / "attr.fmu", md=lambda xml: xml.replace(
        "<ScalarVariable ", '<ScalarVariable colour="red" ', 1))
    no_reference = _rewrite(good, tmp_path / "vr.fmu", md=lambda xml: re.sub(
        r' valueReference="0"', "", xml, count=1))
    not_xml = _rewrite(good, tmp_path / "xml.fmu", md=lambda xml: xml[: len(xml) // 2])
    for path in (bad_attribute, no_reference, not_xml):
        with pytest.raises(Exception):  # noqa: B017 - FMPy raises plain and lxml exceptions
            fmpy.read_model_description(str(path), validate=True)
        with pytest.raises(ValueError, match=r"invalid modelDescription\.xml") as info:
            check_fmu(path)
        assert str(path) in str(info.value)
    with pytest.raises(ValueError, match="Failed to validate modelDescription"):
        check_fmu(bad_attribute)
    # twice (the schema is compiled once), and the same description as FMPy's validating reader
    for _ in range(2):
        md = check_fmu(good)
    reference = fmpy.read_model_description(str(good), validate=True)
    assert md.guid == reference.guid
    assert [(v.name, v.valueReference, v.start) for v in md.modelVariables] == [
        (v.name, v.valueReference, v.start) for v in reference.modelVariables]
    shutil.rmtree(tmp_path)
