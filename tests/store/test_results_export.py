"""cosimstep results: a stored run out as CSV, Parquet or a MATLAB file, values unchanged."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from click.testing import CliRunner

from cosimstep.cli import main
from cosimstep.store import read_run


@pytest.fixture()
def stored(examples, tmp_path):
    db = tmp_path / "r.db"
    res = CliRunner().invoke(main, ["run", str(examples / "linear_coupled.toml"), "--until",
                                    "0.2", "--step", "0.01", "--out", str(db)])
    assert res.exit_code == 0, res.output
    return db


def test_csv_parquet_and_mat_hold_the_stored_values(stored, tmp_path):
    import pandas as pd
    from scipy.io import loadmat

    run = read_run(stored)
    runner = CliRunner()
    for suffix in ("csv", "parquet", "mat"):
        res = runner.invoke(main, ["results", str(stored), "-o", str(tmp_path / f"r.{suffix}"),
                                   "--variables", "fast.u,slow.w"])
        assert res.exit_code == 0, res.output
    cols = [run.names.index("fast.u"), run.names.index("slow.w")]
    with (tmp_path / "r.csv").open() as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["t", "fast.u", "slow.w"]
    assert np.array_equal(np.array(rows[1:], dtype=float),
                          np.column_stack([run.times, run.values[:, cols]]))  # bit for bit
    frame = pd.read_parquet(tmp_path / "r.parquet")
    assert list(frame.columns) == ["fast.u", "slow.w"]
    assert np.array_equal(frame.to_numpy(), run.values[:, cols])
    mat = loadmat(tmp_path / "r.mat")
    assert np.array_equal(mat["fast_u"].ravel(), run.values[:, cols[0]])
    assert np.array_equal(mat["t"].ravel(), run.times)


def test_bad_export_requests_are_configuration_errors(stored, tmp_path):
    runner = CliRunner()
    res = runner.invoke(main, ["results", str(stored), "-o", str(tmp_path / "r.xlsx")])
    assert res.exit_code == 2 and "unknown format" in res.output
    res = runner.invoke(main, ["results", str(stored), "-o", str(tmp_path / "r.csv"),
                               "--variables", "fast.q"])
    assert res.exit_code == 2 and "no output(s) fast.q" in res.output
    assert "its outputs: fast.u, fast.v, slow.w" in res.output
    res = runner.invoke(main, ["results", str(tmp_path / "none.db"), "-o",
                               str(tmp_path / "r.csv")])
    assert res.exit_code == 2 and "Traceback" not in res.output
