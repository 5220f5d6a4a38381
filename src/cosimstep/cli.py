"""Command line: ``cosimstep run | validate | info | plot | demo | models``.

Exit codes: 0 success, 1 the run failed (a sub-model failed, a step could not be taken), 2 the
configuration or the command line is wrong (every problem listed).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sqlite3
import sys
import warnings
from pathlib import Path
from typing import Any

import click

from cosimstep.adapters.fmu_base import set_fmu_logging
from cosimstep.config import SystemSpec, load_system
from cosimstep.controllers import (
    CONTROLLERS,
    DEFAULT_ADAPTIVE,
    controller_options,
    make_controller,
    merged_settings,
    plain_error,
)
from cosimstep.errors import ConfigurationError, Problem, RunInterrupted, is_number
from cosimstep.iteration import COUPLINGS
from cosimstep.masters import COUPLING_INPUTS, MASTERS, RESYNC, MasterOptions, trapezoidal_refusal
from cosimstep.simulate import SimulationResult, simulate
from cosimstep.writable import output_problems

EXIT_FAILED, EXIT_CONFIG = 1, 2


def _tables(db: str) -> set[str]:
    """The tables of the SQLite file ``db``, opened read-only (none if it is no database)."""
    try:
        with sqlite3.connect(f"{Path(db).resolve().as_uri()}?mode=ro", uri=True) as con:
            return {r[0] for r in con.execute("SELECT name FROM sqlite_master "
                                              "WHERE type = 'table'")}
    except sqlite3.Error:
        return set()


def _config_exit(exc: ConfigurationError) -> None:
    """Exit 2 listing every problem on stderr; a command asked for ``--json`` also prints
    them as one JSON object on stdout (status ``invalid``), so a script reading stdout sees
    why there is no result."""
    click.echo(str(exc), err=True)
    context = click.get_current_context(silent=True)
    if context is not None and context.params.get("as_json"):
        click.echo(json.dumps({"status": "invalid", "source": exc.source,
                               "problems": [dataclasses.asdict(p) for p in exc.problems]},
                              indent=2))
    sys.exit(EXIT_CONFIG)


def _load(path: str, until: float | None = None) -> SystemSpec:
    try:
        return load_system(path, until)
    except ConfigurationError as exc:
        _config_exit(exc)
        raise  # unreachable


@click.group()
@click.version_option(package_name="cosimstep")
def main() -> None:
    """cosimstep: adaptive, multi-rate co-simulation of black-box sub-models."""
    # a warning is a sentence for the user here, not a source line of cosimstep's
    warnings.formatwarning = lambda message, category, *_, **__: \
        f"{category.__name__}: {message}\n"


@main.command()
@click.argument("system", type=click.Path(dir_okay=False))
@click.option("--until", type=float, help="End time [s] (default: the file's `until`).")
@click.option("--master", type=click.Choice(MASTERS), help="Coupling scheme.")
@click.option("--extrapolation", type=click.IntRange(0, 2), help="Input extrapolation order.")
@click.option("--interpolation", help="Multirate: how partners' trajectories are read "
              "(hold, linear, pchip, spline-not-a-knot, ...; default: local cubic).")
@click.option("--resync", type=click.Choice(RESYNC), help="Multirate: after an event found "
              "inside a step, roll back only the sub-models it reaches (partial, default) or "
              "every sub-model past it (complete).")
@click.option("--coupling", type=click.Choice(COUPLINGS), help="explicit (one pass per step, "
              "default) or strong coupling: every step repeated until the exchanged values "
              "agree (fixed-point, aitken, iqn-ils).")
@click.option("--coupling-tol", type=float, help="Strong coupling: converged when every "
              "exchanged value's residual is within TOL * (1 + |value|) (default 1e-8).")
@click.option("--max-iterations", type=int, help="Strong coupling: passes per step before it "
              "fails (default 50).")
@click.option("--coupling-input", type=click.Choice(COUPLING_INPUTS), help="Strong coupling: "
              "inputs over a step follow the polynomial through the iterated end value "
              "(polynomial, default: accurate) or are held at the mean of the two end values "
              "(trapezoidal: stable at fixed steps far beyond a stiff coupling's period; "
              "refused with an adaptive controller).")
@click.option("--controller", type=click.Choice(sorted(CONTROLLERS)), help="Step controller.")
@click.option("--step", type=float, help="Fixed step (controller fixed) or initial step [s].")
@click.option("--tol", type=float,
              help="Tolerance of an adaptive controller: the sum of its local error estimates "
              "over the run, in |e| / (1 + |y|) (atol = rtol = tol; set apart with --opt atol=.. "
              "--opt rtol=..), is aimed at TOL/2, |y| taken at the lowest point each output keeps "
              "returning to; pc lets errors it measured to fade within a "
              "time M count over M only (--opt overrun=true: and tightens its steps once its "
              "own estimate exceeds TOL). Where pc's own estimate ends above 2 x TOL (under "
              "multirate: and its time shift is most of it, or it is past 10 x TOL), the run "
              "is repeated once at "
              "TOL reduced by the factor it missed by, without the error memory where the "
              "summed estimate is mostly a time shift (a limit cycle's phase error; see "
              "--no-tighten). --json reports the "
              "measured error in that norm (error.max_scaled, with a reference) and the "
              "run's own estimate (error_estimate).")
@click.option("--no-tighten", is_flag=True, help="One run, whatever its own estimate says "
              "(without it, pc repeats a run whose estimate exceeds 2 x TOL, under multirate "
              "only where that estimate is mostly a time shift or past 10 x TOL, once at a "
              "tighter TOL, kept "
              "unless it failed or estimates itself no better; both runs are stored, --json "
              "describes the other one as "
              "`tightened`; with the default --estimate sum a kept repeat's error_estimate is "
              "its own (`tightened.estimate_alone`) times the first run's error measured "
              "against it (`tightened.error`) over the first run's estimate).")
@click.option("--estimate", type=click.Choice(["sum", "rerun", "richardson"]), default="sum",
              show_default=True,
              help="How an adaptive run estimates its own global error (error_estimate): sum "
              "of the local estimates (free; pc carries the part along the outputs' motion "
              "as a time shift, met at the motion's later speed; too large where errors "
              "decay, too small where they grow); rerun at 10x TOL first and take a ninth "
              "of the difference; or "
              "richardson: the same run beside it at doubled steps (controller pc, "
              "gauss-seidel or jacobi master; the closest at tight TOL). Both cost about "
              "50 % more calls, reported as error_estimate_calls.")
@click.option("--seed", type=int, help="Seed of the random controller.")
@click.option("--opt", "options", multiple=True, metavar="KEY=VALUE",
              help="Controller option, repeatable, e.g. --opt mode=reference --opt hmax=0.02.")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="Set a parameter without editing the file: a shared one (l2=0.5) or one "
              "sub-model's (bar2.l2=0.5; any TOML value, e.g. 'room.mode=\"eco\"'); "
              "repeatable.")
@click.option("--start", "starts", multiple=True, metavar="NAME=VALUE",
              help="Set a start value the same way (theta1=0.3 or bar1.theta1=0.3).")
@click.option("--out", type=click.Path(dir_okay=False), help="SQLite results file "
              "(default: <system name>.db in the current directory).")
@click.option("--no-store", is_flag=True, help="Keep the results in memory only (no file).")
@click.option("--max-wall", type=float, metavar="S", help="Wall-time budget [s]: the run ends "
              "timed_out (exit 1) with everything computed so far stored.")
@click.option("--max-calls", type=int, metavar="N", help="Budget of sub-model calls, likewise.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON summary object.")
@click.option("--output-interval", type=float, metavar="DT", help="Store the values every DT "
              "seconds (linear between the run's points) instead of at every point.")
@click.option("--output-steps", is_flag=True, help="With --output-interval: every accepted "
              "point as well.")
@click.option("--call-timeout", type=float, metavar="S", help="Seconds one sub-model call may "
              "take before the run ends failed with the results so far (0: no limit; default: "
              "the file's [master] call_timeout, else 60).")
@click.option("--inputs", "inputs_csv", type=click.Path(dir_okay=False), metavar="CSV",
              help="One FMU run alone (SYSTEM is an .fmu): its inputs from a CSV file, first "
              "column time, the others named after the inputs (linear between rows, held "
              "outside; two rows with one time: a step change there).")
@click.option("--fmu-logging", is_flag=True, help="Instantiate FMUs with logging on and "
              "echo every message they log to stderr as it comes.")
@click.option("--checkpoint-every", type=float, default=60.0, show_default=True, metavar="S",
              help="Synchronous runs storing every point: write a checkpoint every S "
              "seconds of wall time (0: none), which --resume continues from.")
@click.option("--checkpoint-steps", type=int, metavar="N", help="A checkpoint every N steps "
              "as well.")
@click.option("--resume", "resume_db", type=click.Path(dir_okay=False), metavar="DB",
              help="Continue an interrupted or killed run stored in DB from its last "
              "checkpoint (same SYSTEM and options); it keeps its id and ends as if it had "
              "never stopped.")
@click.option("--run", "run_id", type=int, metavar="ID", help="With --resume: which run "
              "(default: the newest in DB).")
@click.option("-v", "--verbose", is_flag=True, help="A failed run also prints its traceback, "
              "the sub-model's own exception included (on stderr).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar and only the status line "
              "(the exit code says the rest).")
def run(system: str, until: float | None, master: str | None, extrapolation: int | None,
        interpolation: str | None, resync: str | None, coupling: str | None,
        coupling_tol: float | None, max_iterations: int | None, coupling_input: str | None,
        controller: str | None,
        step: float | None, tol: float | None, no_tighten: bool, estimate: str,
        seed: int | None, options: tuple[str, ...], params: tuple[str, ...],
        starts: tuple[str, ...],
        out: str | None, no_store: bool, max_wall: float | None, max_calls: int | None,
        as_json: bool, output_interval: float | None, output_steps: bool,
        call_timeout: float | None, inputs_csv: str | None, fmu_logging: bool,
        checkpoint_every: float, checkpoint_steps: int | None, resume_db: str | None,
        run_id: int | None, verbose: bool, quiet: bool) -> None:
    """Co-simulate SYSTEM (a TOML system file or an SSP archive, .ssp).

    With --tol and no --controller the default adaptive controller runs.
    """
    bad = _flag_problems(until, max_wall, max_calls, output_interval, output_steps,
                         call_timeout)
    if verbose and quiet:
        bad.append(Problem("-v / -q", "ask for more and for less output at once",
                           "leave out one of them"))
    bad += _checkpoint_problems(checkpoint_every, checkpoint_steps, resume_db, run_id, out,
                                no_store, output_interval)
    if out is not None and not no_store and resume_db is None:
        bad += output_problems("--out", out, store=True)
    overrides = {"parameters": _values(params, "--param", bad),
                 "start": _values(starts, "--start", bad)}
    chosen = _options(options, bad)
    # every problem at once: the command line's, the file's, and those of the master and the
    # controller the two make together (as far as the file could be read)
    timeout_ok = not any(p.where == "--call-timeout" for p in bad)  # reported once
    choices = Choices(master, extrapolation, interpolation, resync,
                      call_timeout if timeout_ok else None,
                      {"coupling": coupling, "coupling_tol": coupling_tol,
                       "max_iterations": max_iterations, "coupling_input": coupling_input},
                      controller, step, tol, seed, chosen)
    set_fmu_logging(fmu_logging)
    try:
        spec = load_system(system, until, overrides, inputs=inputs_csv)
    except ConfigurationError as exc:
        if exc.defaults is not None:
            bad += choices.problems(*exc.defaults, None)
        _config_exit(ConfigurationError([*bad, *exc.problems], exc.source))
    bad += choices.problems(spec.master, spec.controller, spec.system)
    if bad:
        _config_exit(ConfigurationError(bad, spec.source))
    checkpoints = {"checkpoint_every": checkpoint_every or None,
                   "checkpoint_steps": checkpoint_steps}
    if resume_db is not None:
        checkpoints["resume"] = _resumable(resume_db, run_id)
    result = _run(spec, master, extrapolation, controller, step, tol, seed,
                  resume_db or out, chosen, interpolation, estimate,
                  store=not no_store,
                  budget={"max_wall": max_wall, "max_calls": max_calls, **checkpoints,
                          "tighten": not no_tighten},
                  resync=resync, progress=False if quiet else None, call_timeout=call_timeout,
                  coupling={"coupling": coupling, "coupling_tol": coupling_tol,
                            "max_iterations": max_iterations, "coupling_input": coupling_input},
                  output=(output_interval, output_steps))
    if quiet and not as_json:
        click.echo(f"status: {result.status} — {result.message}")
    else:
        _report(result, as_json)
    if verbose and result.traceback:
        click.echo(result.traceback, err=True, nl=False)
    sys.exit(0 if result.success else EXIT_FAILED)


def _flag_problems(until: float | None, max_wall: float | None, max_calls: int | None,
                   output_interval: float | None, output_steps: bool,
                   call_timeout: float | None) -> list[Problem]:
    """What is wrong with the numeric flags of :func:`run`."""
    bad = [Problem(flag, f"must be a positive number, got {value}", fix)
           for flag, value, fix in (("--until", until, "e.g. --until 10"),
                                    ("--max-wall", max_wall, "e.g. --max-wall 60"),
                                    ("--max-calls", max_calls, "e.g. --max-calls 100000"),
                                    ("--output-interval", output_interval,
                                     "e.g. --output-interval 0.01"))
           if value is not None and not (math.isfinite(value) and value > 0)]
    if output_steps and output_interval is None:
        bad.append(Problem("--output-steps", "keeps every point beside a grid",
                           "give --output-interval DT too (without it every point is stored)"))
    if call_timeout is not None and not (math.isfinite(call_timeout) and call_timeout >= 0):
        bad.append(Problem("--call-timeout", f"must be 0 (no limit) or positive, got "
                           f"{call_timeout}", "e.g. --call-timeout 60"))
    return bad


def _checkpoint_problems(every: float, steps: int | None, resume_db: str | None,
                         run_id: int | None, out: str | None, no_store: bool,
                         output_interval: float | None) -> list[Problem]:
    """What is wrong with the checkpoint and resume flags (see :func:`run`)."""
    bad = []
    if not (math.isfinite(every) and every >= 0):
        bad.append(Problem("--checkpoint-every", f"must be 0 (none) or positive, got {every}",
                           "e.g. --checkpoint-every 60"))
    if steps is not None and steps <= 0:
        bad.append(Problem("--checkpoint-steps", f"must be positive, got {steps}",
                           "e.g. --checkpoint-steps 10000"))
    if run_id is not None and resume_db is None:
        bad.append(Problem("--run", "names the run to resume", "give --resume DB too"))
    if resume_db is not None and (no_store or out is not None or output_interval is not None):
        bad.append(Problem("--resume", "continues the run in DB, storing every point there",
                           "leave out --out, --no-store and --output-interval"))
    if resume_db is not None and not Path(resume_db).is_file():
        bad.append(Problem("--resume", f"no results store '{resume_db}'",
                           "name the .db a checkpointed run wrote (see `cosimstep runs DB`)"))
    if out is not None and no_store:
        bad.append(Problem("--out", "names the results store, --no-store keeps none",
                           "leave out one of them"))
    return bad + _ignored_checkpoints(every, steps, no_store, output_interval)


def _ignored_checkpoints(every: float, steps: int | None, no_store: bool,
                         output_interval: float | None) -> list[Problem]:
    """Checkpoints asked for where none can be written: without a store, or on a grid."""
    # --checkpoint-every has a default: only one given on the command line is asked for
    context = click.get_current_context(silent=True)
    given_every = context is not None and context.get_parameter_source(
        "checkpoint_every") is click.core.ParameterSource.COMMANDLINE
    asked = [flag for flag, value in (("--checkpoint-every", given_every and every),
                                      ("--checkpoint-steps", steps)) if value]
    bad = []
    for why, fix, given in (("--no-store keeps no store to write them to", "leave out "
                             "--no-store", no_store),
                            ("a run stored on a grid (--output-interval) cannot be resumed",
                             "leave out --output-interval", output_interval is not None)):
        bad += [Problem(flag, f"writes checkpoints, but {why}", fix) for flag in asked if given]
    return bad


def _resumable(db: str, run_id: int | None) -> int:
    """The id of the run in ``db`` to resume (exit 2 saying why there is none)."""
    from cosimstep.store import read_checkpoint

    try:
        return read_checkpoint(db, run_id).run_id
    except (ValueError, sqlite3.Error) as exc:
        _config_exit(ConfigurationError([Problem("--resume", str(exc),
                                                 "see `cosimstep runs DB`")], db))
    raise AssertionError  # unreachable: _config_exit exits


def _values(pairs: tuple[str, ...], flag: str, bad: list[Problem]) -> dict[str, Any]:
    """``NAME=VALUE`` pairs (every malformed one added to ``bad``). A value is a number; one
    sub-model's (``MODEL.NAME``) may also be any TOML value, as in its table of the file —
    text in quotes (``--param 'room.mode="eco"'``), ``true``/``false``, an array."""
    out = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        key = key.strip()
        try:
            value: Any = float(text)
        except ValueError:  # one sub-model's parameter may be any TOML value (not a start)
            value = _toml_value(text) if flag == "--param" and "." in key else None
        number = is_number(value)
        if not sep or not key or value is None or (number and not math.isfinite(value)) \
                or not (number or "." in key):
            bad.append(Problem(f"{flag} {pair}", "expected NAME=NUMBER, or MODEL.NAME=VALUE "
                               "with a TOML value", f"e.g. {flag} NAME=0.5 (a shared value), "
                               f"{flag} MODEL.NAME=0.5 or {flag} 'MODEL.NAME=\"text\"' (one "
                               "sub-model's)"))
            continue
        out[key] = float(value) if number else value
    return out


def _toml_value(text: str) -> Any:
    """``text`` read as a TOML value (``None`` if it is none)."""
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return None


def _options(pairs: tuple[str, ...], bad: list[Problem]) -> dict[str, Any]:
    """``--opt KEY=VALUE`` pairs (every malformed one added to ``bad``)."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            bad.append(Problem(f"--opt {pair}", "expected KEY=VALUE", "e.g. --opt hmax=0.02"))
            continue
        try:
            value: Any = json.loads(text)
        except json.JSONDecodeError:
            value = text  # a bare word such as mode=reference
        out[key.strip()] = value
    return out


def _run(spec: SystemSpec, master: str | None, extrapolation: int | None,
         controller: str | None, step: float | None, tol: float | None, seed: int | None,
         out: str | None, options: dict[str, Any] | None = None,
         interpolation: str | None = None, estimate: str = "sum", *,
         store: bool = True, budget: dict[str, Any] | None = None,
         resync: str | None = None, progress: bool | None = None,
         call_timeout: float | None = None,
         output: tuple[float | None, bool] = (None, False),
         coupling: dict[str, Any] | None = None) -> SimulationResult:
    opts = _master_options(spec, master, extrapolation, interpolation, resync, call_timeout,
                           coupling)
    if resync is not None and opts.name != "multirate":
        _config_exit(ConfigurationError([Problem(
            "--resync", f"chooses how the multirate master goes back to an event; this run's "
            f"master is '{opts.name}'", "add --master multirate or leave out --resync")],
            "the command line"))
    settings = _controller_settings(spec, controller, step, tol, seed, options)
    name = settings.pop("name", None)
    ctrl = _controller(name, settings, spec.source)
    _check_scheme(ctrl, opts, spec)
    _check_estimate(estimate, ctrl, spec, opts)
    db = (out or f"{spec.name}.db") if store else None
    if db is not None and out is None:  # the default store, named after the system
        problems = output_problems("the results store", db, store=True)
        if problems:
            _config_exit(ConfigurationError(problems, "the command line (name one with --out, "
                                            "or run with --no-store)"))
    try:
        return simulate(spec.system, spec.until, ctrl, opts, reference=spec.reference,
                        store=db, name=spec.name,
                        config={"source": spec.source, "system": spec.raw},
                        progress=progress, estimate=estimate, output_interval=output[0],
                        output_steps=output[1], **(budget or {}))
    except RunInterrupted as exc:  # stored; reported as any ended run (exit 1)
        return exc.result
    except ValueError as exc:
        if (budget or {}).get("resume") is None:
            raise
        _config_exit(ConfigurationError([Problem("--resume", str(exc),
                                                 "resume with the same system and options")],
                                        spec.source))
    raise AssertionError  # unreachable: _config_exit exits


def _controller(name: str | None, settings: dict[str, Any], source: str) -> Any:
    """The controller, or exit 2 saying what is wrong (an unknown option: the valid ones)."""
    ctrl, problems = _built_controller(name, settings)
    if problems:
        _config_exit(ConfigurationError(problems, source))
    return ctrl


def _built_controller(name: str | None, settings: dict[str, Any]) -> tuple[Any, list[Problem]]:
    """The controller, or ``None`` and what is wrong: every unknown option (with the valid
    ones), then what the controller refuses of the rest."""
    settings = dict(settings)
    problems = []
    effective = name if name is not None else \
        DEFAULT_ADAPTIVE if settings.get("tol") is not None else "fixed"
    # (a controller that wraps another hands it options its own list does not name)
    if effective in CONTROLLERS and effective not in WRAPPERS:
        options = controller_options(effective)
        for key in [k for k in settings if k not in {*options, "step", "tol"}]:
            settings.pop(key)
            problems.append(Problem("controller", f"unknown option '{key}'",
                                    f"its options: {', '.join(options)}"))
    try:
        ctrl = make_controller(name, settings.pop("step", None), settings.pop("tol", None),
                               **settings)
        return (ctrl, []) if not problems else (None, problems)
    except TypeError as exc:
        fix = f"its options: {', '.join(controller_options(name))}" \
            if name in CONTROLLERS or name is None else "see `cosimstep run --help`"
        return None, [*problems, Problem("controller", plain_error(exc), fix)]
    except ValueError as exc:
        fix = ("correct it where it is set: --tol, --step, --opt KEY=VALUE, or the file's "
               "[controller] table") + (f"; options of '{name}': "
                                        f"{', '.join(controller_options(name))}"
                                        if name in CONTROLLERS else "")
        return None, [*problems, Problem("controller", str(exc), fix)]


WRAPPERS = frozenset({"switching", "adaptive-tol"})
"""Controllers that pass options on to a controller inside them (:func:`_built_controller`)."""


@dataclasses.dataclass
class Choices:
    """What ``run``'s command line chooses for the master and the controller, checked on top of
    a file's ``[master]`` and ``[controller]`` before anything runs (:meth:`problems`)."""

    master: str | None
    extrapolation: int | None
    interpolation: str | None
    resync: str | None
    call_timeout: float | None
    coupling: dict[str, Any]
    controller: str | None
    step: float | None
    tol: float | None
    seed: int | None
    options: dict[str, Any]

    def problems(self, master: MasterOptions | None, controller: dict[str, Any] | None,
                 system: Any) -> list[Problem]:
        """What is wrong with these choices on top of the file's ``master`` and
        ``controller`` (either ``None``: the file's table has problems of its own, listed
        already, so it is not checked again); ``system`` (``None`` if it could not be built)
        refines the check of an explicit coupling's options."""
        problems = []
        if master is not None:
            problems += _master_choice(master, system, self.master, self.extrapolation,
                                       self.interpolation, self.resync, self.call_timeout,
                                       self.coupling)[1]
        if controller is not None:
            settings = merged_settings(controller, self.controller, self.step, self.tol,
                                       self.seed, self.options)
            problems += _built_controller(settings.pop("name", None), settings)[1]
        return problems


def _master_options(spec: SystemSpec, master: str | None, extrapolation: int | None,
                    interpolation: str | None, resync: str | None = None,
                    call_timeout: float | None = None,
                    coupling: dict[str, Any] | None = None) -> MasterOptions:
    """The file's ``[master]`` with the command line's choices on top (exit 2 if invalid);
    ``call_timeout`` 0 lifts the limit; ``coupling``: ``coupling``, ``coupling_tol``,
    ``max_iterations`` and ``coupling_input`` given on the command line (``None``: the
    file's)."""
    opts, problems = _master_choice(spec.master, spec.system, master, extrapolation,
                                    interpolation, resync, call_timeout, coupling)
    if problems:
        _config_exit(ConfigurationError(problems, spec.source))
    return opts


def _master_choice(file: MasterOptions, system: Any, master: str | None,
                   extrapolation: int | None, interpolation: str | None, resync: str | None,
                   call_timeout: float | None, coupling: dict[str, Any] | None
                   ) -> tuple[MasterOptions, list[Problem]]:
    """:func:`_master_options` on the file's options ``file``, returning what is wrong
    instead of exiting (``system``: ``None`` if it could not be built)."""
    timeout = file.call_timeout if call_timeout is None else call_timeout
    opts = MasterOptions(master or file.name,
                         file.extrapolation if extrapolation is None else extrapolation,
                         file.order, timeout, interpolation or file.interpolation,
                         resync or file.resync)
    strong = {k: getattr(file, k) for k in ("coupling", "coupling_tol", "max_iterations",
                                            "coupling_input")}
    strong.update({k: v for k, v in (coupling or {}).items() if v is not None})
    opts = dataclasses.replace(opts, **strong)
    problems = [Problem("master", p, "see `cosimstep run --help`") for p in opts.problems()]
    if opts.coupling == "explicit":  # what only an iteration reads would change nothing
        given = [(flag, key) for flag, key in (("--coupling-tol", "coupling_tol"),
                                               ("--max-iterations", "max_iterations"))
                 if (coupling or {}).get(key) is not None]
        if given and given[0][1] == "coupling_tol" and (system is None or system.loops()):
            given = given[1:]  # algebraic loops are solved to coupling_tol
        problems += [Problem(flag, "sets the iteration of strong coupling; this run's coupling "
                             "is explicit", "add --coupling fixed-point|aitken|iqn-ils, or "
                             "leave it out") for flag, _ in given]
    return opts, problems


def _controller_settings(spec: SystemSpec, controller: str | None, step: float | None,
                         tol: float | None, seed: int | None,
                         options: dict[str, Any] | None) -> dict[str, Any]:
    """The file's ``[controller]`` with the command line's choices on top."""
    return merged_settings(spec.controller, controller, step, tol, seed, options)


def _check_scheme(ctrl: Any, opts: MasterOptions, spec: SystemSpec) -> None:
    """Refuse (exit 2, every reason) a controller or master the sub-models cannot serve."""
    problems = []
    multirate = opts.name == "multirate"
    if multirate and getattr(ctrl, "policy", None) is None:
        problems.append(Problem("controller", "the multirate master steps every sub-model "
                                "with a controller's error policy (pc, corrector, defect, "
                                f"doubling, embedded); '{ctrl.name}' has none",
                                "give --tol TOL alone (pc), or --controller pc"))
    unable = [n for n, m in spec.system.models.items() if not m.capabilities.can_save_state]
    if unable and (ctrl.needs_rollback or multirate):
        what = f"controller '{ctrl.name}'" if ctrl.needs_rollback else "the multirate master"
        problems.append(Problem("controller", f"{what} rejects and re-runs steps, but "
                                f"{', '.join(unable)} cannot save and restore its state",
                                "use a fixed step (--controller fixed --step H) with the "
                                "gauss-seidel or jacobi master"))
    if ctrl.needs_rollback and opts.coupling_input == "trapezoidal":
        problems.append(Problem("coupling_input", trapezoidal_refusal(ctrl.name),
                                "use a fixed step (--controller fixed --step H) with it, or "
                                "the polynomial input with an adaptive controller"))
    if unable and opts.coupling != "explicit":
        problems.append(Problem("coupling", f"coupling '{opts.coupling}' repeats every step "
                                f"from the saved states, but {', '.join(unable)} cannot save "
                                "and restore its state", "use --coupling explicit"))
    from cosimstep.adapters.fmu_base import once_per_process_problems

    problems += [Problem("models", reason, "keep one instance of it, or run the systems that need "
                         "more in separate processes")
                 for reason in once_per_process_problems(spec.system.models)]
    if multirate:
        from cosimstep.multirate import refusals

        problems += [Problem("--master multirate", reason, "use --master gauss-seidel or jacobi")
                     for reason in refusals(spec.system.models, opts.interpolation,
                                            state=False)]
    if problems:
        _config_exit(ConfigurationError(problems, spec.source))


def _check_estimate(estimate: str, ctrl: Any, spec: SystemSpec, opts: Any) -> None:
    """What ``--estimate`` cannot do for this run (exit 2, every problem at once)."""
    from cosimstep.simulate import estimate_problems

    problems = [Problem("--estimate", what, fix)
                for what, fix in estimate_problems(estimate, ctrl, opts)]
    if problems:
        _config_exit(ConfigurationError(problems, spec.source))


def _report(result: SimulationResult, as_json: bool) -> None:
    summary = result.summary()
    if as_json:
        click.echo(json.dumps(summary, indent=2))
        return
    click.echo(f"status: {summary['status']} — {summary['message']}")
    click.echo(f"t_end: {summary['t_end']:.6g} s   calls: {summary['calls_total']} "
               f"({', '.join(f'{k} {v}' for k, v in summary['calls'].items())})")
    click.echo(f"steps: {summary['steps_accepted']} accepted, {summary['steps_rejected']} "
               f"rejected, h in [{summary['h_min']}, {summary['h_max']}]")
    if "error" in summary:
        e = summary["error"]
        click.echo(f"error vs monolithic reference: max {e['max_abs']:.3e}, rmse {e['rmse']:.3e}"
                   f", max |e|/(1+|y|) {e['max_scaled']:.3e}"
                   + (f" at each sub-model's own points ({e['grid_max_scaled']:.3e} on the "
                      "common grid, interpolated between them)" if "grid_max_scaled" in e else ""))
    other = summary.get("tightened")
    if other is not None and other["run"] == "first":
        measured = f", measured against this run {other['error'] / other['tol']:.3g} x tol" \
            if other.get("error") is not None else ""
        click.echo(f"repeated at a tighter tol: the run at tol {other['tol']:.3g} estimated "
                   f"{other['error_estimate'] / other['tol']:.3g} x tol{measured} "
                   f"({other['calls']} calls more, not counted above)")
    elif other is not None:
        how = f"estimated its own error at {other['error_estimate']:.3g}, no lower than this " \
            "run's" if other["status"] == "ok" and other["error_estimate"] is not None \
            else f"ended {other['status']}"
        click.echo(f"a repeat at tol {other['tol']:.3g} {how} and was not kept "
                   f"({other['calls']} calls more, not counted above)")
    if summary.get("error_estimate") is not None:
        cost = summary["error_estimate_calls"]
        click.echo(f"estimated coupling error (own, no reference; a sub-model's own "
                   f"integration error is not in it): {summary['error_estimate']:.3e}"
                   + (f" (estimate cost {cost} calls)" if cost else ""))
    click.echo(f"wall: {summary['wall_s']:.2f} s   store: "
               f"{summary['store'] or 'none (--no-store)'}")


@main.command()
@click.argument("system", type=click.Path(dir_okay=False))
def validate(system: str) -> None:
    """Check SYSTEM and list every problem (exit 2 if there are any)."""
    spec = _load(system)
    if spec.controller:  # the file's run defaults must build, as `run` will build them
        ctrl = _controller(spec.controller.get("name", DEFAULT_ADAPTIVE if "tol" in
                                               spec.controller else None),
                           {k: v for k, v in spec.controller.items() if k != "name"},
                           spec.source)
        _check_scheme(ctrl, spec.master, spec)
    click.echo(f"{system}: ok — {len(spec.system.models)} models, "
               f"{len(spec.system.connections)} connections"
               + (", with monolithic reference" if spec.reference else ""))
    for ports in spec.system.loops():  # solved at every communication point, not refused
        click.echo(f"algebraic loop (solved at every communication point): {', '.join(ports)}")


@main.command("sweep")
@click.argument("system", type=click.Path(dir_okay=False))
@click.option("--param", "params", multiple=True, required=True,
              help="A swept name and its values: NAME=V1,V2,... (full design) or NAME=LOW:HIGH "
              "(lhs, sobol). NAME: a parameter of the file (l2, bar2.l2), a start value "
              "(start.theta1) or a run option (tol, step, until). Repeatable.")
@click.option("--design", "design_kind", type=click.Choice(["full", "lhs", "sobol"]),
              default="full", show_default=True, help="Full factorial of the listed values, "
              "or a Latin hypercube / scrambled Sobol sample of the ranges.")
@click.option("--samples", type=int, help="Points of a sampled design.")
@click.option("--seed", type=int, help="Seed of a sampled design.")
@click.option("--master", type=click.Choice(MASTERS), help="Coupling scheme of every run.")
@click.option("--extrapolation", type=click.IntRange(0, 2), help="Input extrapolation order.")
@click.option("--controller", type=click.Choice(sorted(CONTROLLERS)), help="Step controller.")
@click.option("--tol", type=float, help="Tolerance of every run (unless swept).")
@click.option("--step", type=float, help="Fixed or initial step of every run (unless swept).")
@click.option("--until", type=float, help="End time of every run (unless swept).")
@click.option("--coupling", type=click.Choice(COUPLINGS), help="Strong coupling of every run.")
@click.option("--estimate", type=click.Choice(["sum", "rerun", "richardson"]),
              help="How every adaptive run estimates its own error (see `run --help`; "
              "column error_estimate).")
@click.option("--no-tighten", "tighten", flag_value=False, default=None,
              help="One run per point, whatever its own estimate says (see `run --help`; "
              "without it a repeated run's calls_total counts both runs).")
@click.option("--workers", type=click.IntRange(1), help="Worker processes of the local Dask "
              "cluster (default: one per core).")
@click.option("--scheduler", help="Address of an existing Dask scheduler "
              "(tcp://host:8786) instead of a local cluster.")
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="SQLite file of the sweep's table (runs already in it are skipped).")
@click.option("--keep", type=click.Choice(["summary", "traces"]), default="summary",
              show_default=True, help="traces: also each run's whole trajectory, one store "
              "per run in OUT_traces/ (`cosimstep plot`, `results`, read_run read them).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bar.")
def sweep_command(system: str, params: tuple[str, ...], design_kind: str, samples: int | None,
                  seed: int | None, out: str, workers: int | None, scheduler: str | None,
                  keep: str, quiet: bool, **options: Any) -> None:
    """Run SYSTEM at every point of a design, one Dask task per run; summaries to --out.

    The same command run again runs only what is missing; a failed run is recorded with its
    message and the sweep goes on. Exit code 0 once every point has a record, whatever the
    runs' statuses (the last line counts them; `plot-sweep` marks failed points); 2 for a
    refused configuration, before any run.
    """
    from cosimstep.sweep import sweep

    bad = output_problems("--out", out, store=True)
    if design_kind == "full":  # a full factorial takes every listed value, no sample
        bad += [Problem(flag, "sets a sampled design; --design is full", "add --design "
                        "lhs|sobol, or leave it out")
                for flag, value in (("--samples", samples), ("--seed", seed)) if value is not None]
    if keep == "traces" and not bad:
        bad = output_problems("--keep traces", Path(out).with_name(Path(out).stem + "_traces"),
                              folder=True)
    if bad:
        _config_exit(ConfigurationError(bad, "the command line"))
    try:
        frame = sweep(system, list(params), design_kind=design_kind, samples=samples,
                      seed=seed, out=out, workers=workers, scheduler=scheduler,
                      progress=False if quiet else None, keep=keep, **options)
    except ConfigurationError as exc:
        _config_exit(exc)
    except ValueError as exc:  # a design, an axis or a run option the first point refused
        _config_exit(ConfigurationError([Problem("sweep", str(exc),
                                                 "see `cosimstep sweep --help`")],
                                        "the command line"))
    counts = frame["status"].value_counts().to_dict() if len(frame) else {}
    click.echo(f"{len(frame)} runs in {out}: "
               + ", ".join(f"{n} {status}" for status, n in sorted(counts.items())))


@main.command("plot-sweep")
@click.argument("db", type=click.Path(dir_okay=False))
@click.option("--x", "x", help="A swept name for the horizontal axis.")
@click.option("--work-precision", is_flag=True, help="Calls against error, one line per "
              "sweep's run options (sweeps of tol or step with other controllers or masters "
              "into the same file).")
@click.option("--y", "y", help="A second swept name: contours of Z over the X-Y plane.")
@click.option("--z", "z", default="calls_total", show_default=True,
              help="What is drawn: calls_total, error, error_estimate, steps, wall_s or "
              "calls.MODEL.")
@click.option("--linear", is_flag=True, help="Linear axes and colours (default: logarithmic "
              "where the values are positive).")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Figure file (.png, .pdf, .svg).")
def plot_sweep_command(db: str, x: str | None, work_precision: bool, y: str | None, z: str,
                       linear: bool, output: str) -> None:
    """Plot a sweep's runs: Z against X, contours of Z over X and Y (thesis figs. 68-70), or
    the work-precision diagram."""
    from cosimstep.plotting import plot_sweep, plot_work_precision
    from cosimstep.sweep import SweepTable

    bad = output_problems("-o", output)
    if not Path(db).is_file():
        bad.append(Problem("DB", f"no file {db}", "give the --out of a cosimstep sweep"))
    elif "sweep_run" not in (tables := _tables(db)):
        bad.append(Problem("DB", f"{db} holds no sweep table" + (
            " (it is a results store: see `cosimstep runs`, `plot`)"
            if "run" in tables else ""), "give the --out of a cosimstep sweep"))
    if bad:
        _config_exit(ConfigurationError(bad, "the command line"))
    table = SweepTable(db)
    try:
        frame = table.frame()
    finally:
        table.close()
    if work_precision and not frame.empty:
        click.echo(f"wrote {plot_work_precision(frame, output)}")
        return
    if x is None:
        _config_exit(ConfigurationError([Problem("--x", "missing", "give --x NAME or "
                                                 "--work-precision")], "the command line"))
    missing = [n for n in (x, y, z) if n is not None and n not in frame.columns]
    if missing or frame.empty:
        _config_exit(ConfigurationError(
            [Problem(f"--{'xyz'[(x, y, z).index(n)]}", f"'{n}' is not a column of {db}",
                     f"columns: {', '.join(map(str, frame.columns))}") for n in missing]
            or [Problem("DB", f"{db} holds no sweep runs", "run cosimstep sweep first")],
            "the command line"))
    click.echo(f"wrote {plot_sweep(frame, output, x, y, z, log=not linear)}")


@main.command()
@click.argument("fmu", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")
def info(fmu: str, as_json: bool) -> None:
    """Describe FMU: FMI version, kind, capabilities, default experiment, variables."""
    from cosimstep.fmu.info import describe_fmu, format_info

    try:
        described = describe_fmu(fmu)
    except ValueError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_CONFIG)
    click.echo(json.dumps(described, indent=2) if as_json else format_info(described))


@main.command()
@click.argument("db", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Figure file (.png, .pdf, .svg).")
@click.option("--run", "run_id", type=int, help="Run id in the store (default: the last, "
              "passing over a run repeated at a tighter tol that was not kept).")
@click.option("--variables", help="Comma-separated outputs to draw (default: all), e.g. "
              "bar1.theta.")
def plot(db: str, output: str, run_id: int | None, variables: str | None) -> None:
    """Plot a stored run: states above, step size below."""
    from cosimstep.plotting import plot_run
    from cosimstep.store import read_run

    formats = _figure_formats()
    suffix = Path(output).suffix.lower().lstrip(".")
    bad = output_problems("-o", output)
    if suffix not in formats:
        bad.append(Problem("-o", f"'{output}' is not a figure format matplotlib writes",
                           f"end it in one of: .{', .'.join(sorted(formats))}"))
    if bad:
        _config_exit(ConfigurationError(bad, "the command line"))
    try:
        stored = read_run(db, run_id)
    except LookupError as exc:
        fix = "see `cosimstep runs DB` for the runs it holds" if run_id is not None \
            else "is it a cosimstep results store?"
        click.echo(f"error: {db}: {exc} ({fix})", err=True)
        sys.exit(EXIT_CONFIG)
    except (FileNotFoundError, sqlite3.DatabaseError) as exc:
        click.echo(f"error: {db}: {exc} (is it a cosimstep results store?)", err=True)
        sys.exit(EXIT_CONFIG)
    chosen = [v.strip() for v in variables.split(",") if v.strip()] if variables else None
    unknown = [v for v in chosen or [] if v not in stored.names]
    if unknown:
        _config_exit(ConfigurationError([Problem(
            "--variables", f"not an output of the run: {', '.join(unknown)}",
            f"name outputs of the run: {', '.join(stored.names[:20])}"
            + (" …" if len(stored.names) > 20 else ""))], db))
    click.echo(f"wrote {plot_run(stored, output, chosen)}")


@main.command()
@click.argument("db", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output file: .csv, .parquet (needs cosimstep[parquet]) or .mat.")
@click.option("--run", "run_id", type=int, help="Run id in the store (default: the last, "
              "passing over a run repeated at a tighter tol that was not kept).")
@click.option("--variables", help="Comma-separated outputs (default: all), e.g. bar1.theta.")
def results(db: str, output: str, run_id: int | None, variables: str | None) -> None:
    """Export a stored run's values (time and one column per output)."""
    from cosimstep.results import FORMATS, write
    from cosimstep.store import read_run

    problems = output_problems("-o", output)
    if Path(output).suffix.lower() not in FORMATS:
        problems.append(Problem("-o", f"'{output}': unknown format",
                                f"end it in one of {', '.join(FORMATS)}"))
    if Path(output).suffix.lower() == ".parquet" and not _has("pyarrow"):
        problems.append(Problem("-o", "writing Parquet needs pandas and pyarrow",
                                'pip install "cosimstep[parquet]"'))
    try:
        stored = read_run(db, run_id)
    except (FileNotFoundError, LookupError, sqlite3.DatabaseError) as exc:
        problems.append(Problem(db, f"{exc}", "give a cosimstep results store"))
        stored = None
    if problems:
        _config_exit(ConfigurationError(problems, "the command line"))
    chosen = [v.strip() for v in variables.split(",") if v.strip()] if variables else None
    try:
        click.echo(f"wrote {write(stored, output, chosen)}")
    except KeyError as exc:
        _config_exit(ConfigurationError([Problem("--variables", exc.args[0],
                                                 "name outputs of the run")], db))


@main.command("runs")
@click.argument("db", type=click.Path(dir_okay=False))
@click.option("--delete", "delete", type=int, metavar="ID", help="Remove run ID from the store.")
@click.option("--json", "as_json", is_flag=True, help="Print the runs as a JSON list.")
def list_runs(db: str, delete: int | None, as_json: bool) -> None:
    """List the runs in a results store (a killed run shows as abandoned)."""
    from cosimstep.store import delete_run, run_table

    try:
        if delete is not None:
            delete_run(db, delete)
            click.echo(f"deleted run {delete} from {db}")
            return
        table = run_table(db)
    except (FileNotFoundError, LookupError, RuntimeError, sqlite3.DatabaseError) as exc:
        kind = " (it is a sweep table: see `cosimstep plot-sweep`)" \
            if Path(db).is_file() and "sweep_run" in _tables(db) else ""
        click.echo(f"error: {db}: {exc}{kind}", err=True)
        sys.exit(EXIT_CONFIG)
    if as_json:
        click.echo(json.dumps(table, indent=2, default=str))
        return
    click.echo(f"{'id':>4s}  {'status':11s} {'t_end':>9s} {'wall s':>8s}  {'created':19s}  system")
    for r in table:
        t_end = f"{r['t_end']:9.4g}" if r["t_end"] is not None else f"{'-':>9s}"
        wall = f"{r['wall_s']:8.2f}" if r["wall_s"] is not None else f"{'-':>8s}"
        click.echo(f"{r['id']:4d}  {r['status']:11s} {t_end} {wall}  {r['created'][:19]}  "
                   f"{r['system']}" + (" (not the result of its repeated pair)"
                                       if r["kept"] == 0 else ""))


def _has(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def _figure_formats() -> set[str]:
    from matplotlib.backend_bases import FigureCanvasBase

    return set(FigureCanvasBase.get_supported_filetypes())


@main.command()
@click.argument("which", required=False, default="pendulum",
                type=click.Choice(["pendulum", "ship"]))
@click.option("--out", default="cosimstep-demo", show_default=True,
              type=click.Path(file_okay=False), help="Folder for the results and the figure.")
def demo(which: str, out: str) -> None:
    """The toggled double pendulum run three ways (a fixed step, `pc` and multirate at tol
    1e-4), in one figure; or, with `ship`, the ship plant's damage scenario (thesis 1.1)."""
    from cosimstep.demo import run_demo

    try:
        if which == "ship":
            _ship_demo(out)  # exits with the run's status
            return
        runs, db, figure = run_demo(out)
    except RunInterrupted as exc:
        click.echo(f"{exc.result.message}; the runs so far are in {out}", err=True)
        sys.exit(EXIT_FAILED)
    click.echo(f"{'run':26s} {'status':8s} {'calls':>7s} {'max error':>10s} {'wall s':>7s}")
    for run in runs:
        r = run.result
        click.echo(f"{run.label:26s} {r.status:8s} {r.calls_spent:7d} "
                   f"{r.error.max_scaled if r.error else float('nan'):10.2e} {r.wall_s:7.2f}")
    for run in runs:
        if run.result.error is not None and run.result.error.grid_max_scaled is not None:
            click.echo(f"{run.label}: max error at its sub-models' own points; "
                       f"{run.result.error.grid_max_scaled:.2e} interpolated between them")
    click.echo(f"status: {'ok' if all(r.result.success for r in runs) else 'failed'}   "
               f"store: {db} (3 runs)   figure: {figure}")
    sys.exit(0 if all(r.result.success for r in runs) else EXIT_FAILED)


def _ship_demo(out: str) -> None:
    from cosimstep.demo import run_ship_demo

    r, db, figure = run_ship_demo(out)
    trips = [e.t for e in r.events if e.kind == "isolate"]
    hottest = max(float(r[f"zone{i}.T"].max()) for i in (1, 2, 3))
    click.echo(f"ship plant, {r.t_end:g} s: {r.status} ({r.message}); calls "
               + ", ".join(f"{m} {c}" for m, c in r.calls.items()))
    if r.error is not None:
        click.echo(f"error against the monolithic plant: {r.error.max_scaled:.2e} "
                   "(|e| / (1 + |y|), the norm --tol bounds)")
    click.echo(f"section isolated at t = {trips[0]:.4f} s" if trips else "no isolation")
    click.echo(f"hottest zone: {hottest:.2f} degC   store: {db}   figure: {figure}")
    sys.exit(0 if r.success else EXIT_FAILED)


@main.command()
@click.argument("kind")
@click.option("-o", "--output", required=True, type=click.Path(),
              help="The .fmu file to write (or a folder).")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE",
              help="Parameter value, repeatable, e.g. --param l1=0.5.")
@click.option("--start", "starts", multiple=True, metavar="NAME=VALUE",
              help="Start value, repeatable, e.g. --start theta1=0.4.")
def export(kind: str, output: str, params: tuple[str, ...], starts: tuple[str, ...]) -> None:
    """Export the built-in sub-model KIND (see `cosimstep models`) as an FMI 2.0 CS FMU.

    Needs pythonfmu (pip install "cosimstep[export]"); the FMU runs in a Python that can import
    cosimstep.
    """
    try:
        from cosimstep.fmu.export import export_fmu
    except ImportError as exc:
        click.echo(f"error: {exc}; install the extra: pip install 'cosimstep[export]'", err=True)
        sys.exit(EXIT_CONFIG)

    def numbers(pairs: tuple[str, ...], what: str) -> dict[str, float]:
        out = {}
        for pair in pairs:
            key, sep, value = pair.partition("=")
            try:
                out[key.strip()] = float(value)
            except ValueError:
                sep = ""
            if not sep:
                click.echo(f"error: --{what} {pair!r} is not NAME=NUMBER", err=True)
                sys.exit(EXIT_CONFIG)
        return out

    bad = output_problems("-o", output, folder=Path(output).suffix.lower() != ".fmu")
    if bad:
        _config_exit(ConfigurationError(bad, "the command line"))
    try:
        path = export_fmu(kind, output, numbers(params, "param"), numbers(starts, "start"))
    except ValueError as exc:
        click.echo(f"error: {exc}", err=True)
        sys.exit(EXIT_CONFIG)
    click.echo(f"wrote {path}")


@main.command("models")
def list_models() -> None:
    """List the built-in sub-model types."""
    from cosimstep.events import KINDS
    from cosimstep.models import REGISTRY

    rows = {name: kind.description for name, kind in REGISTRY.items()}
    rows.update({name: f"discrete events: {text}" for name, (_, text) in KINDS.items()})
    for name, description in sorted(rows.items()):
        click.echo(f"{name:28s} {description}")
