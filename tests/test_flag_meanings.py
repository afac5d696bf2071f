"""One meaning per flag across the ``bench`` subcommands, and the old spellings refused.

A flag that two commands share means one thing in both: one ``dest`` everywhere, and a help text
that says the meaning declared in :data:`MEANINGS` (``--uncertainty`` absolute, ``--max-seconds`` a
time limit, ``--budget-seconds`` a bench-time budget, ``--out`` what the command writes). A new
flag shared by two commands must be declared here, so a second meaning cannot slip in. Spellings
retired because they meant two things are refused with one line that names the new spelling
(exit 2, as every usage error)."""

from __future__ import annotations

import argparse
import re

import pytest

from bench.cli import build_parser
from tests.helpers.cli import run_main

#: every flag that more than one subcommand takes -> a pattern each of its help texts must match
MEANINGS: dict[str, str] = {
    "--beam": r"\bbeam\b",
    "--bench": r"\bbench\b",
    "--body": r"what executes the bench description",
    "--check": r"only this check",
    "--common-random-numbers": r"one random stream",
    "--criterion": r"log det of the Fisher information",
    "--csv": r"\bCSV\b",
    "--date": r"simulated day",
    "--delta": r"confidence delta",
    "--design": r"\bMODEL\b",
    "--force": r"replace output files",
    "--integration-s": r"integration time",
    "--json": r"\bJSON\b",
    "--like": r"read every point as this plan does",
    "--budget-seconds": r"bench-time budget",
    "--max-seconds": r"\btime limit\b",
    "--no-adaptive": r"instead of the adaptive rule",
    "--out": r"\boutput\b|\bto write\b",
    "--plot": r"\bdraw|\bplot\b",
    "--prior": r"prior guess",
    "--prior-spread": r"prior range",
    "--quiet": r"no progress bar",
    "-q": r"no progress bar",
    "--rays": r"\bray counts?\b|\brays per wavelength\b",
    "--repeats": r"\btimes\b",
    "--seed": r"\bseed\b",
    "--specimen": r"bench specimens",
    "--step": r"step of the in-plane candidate grid",
    "--store": r"\brun store\b|\bas a run\b",
    "--uncertainty": r"\babsolute uncertainty\b",
    "--wavelengths": r"\bnm\b",
}

#: (command, old spelling, new spelling, the arguments around it, a value): the retired spellings
RENAMED = [
    ("gonio", "--uncertainty", "--relative-uncertainty", ["--specimen", "lambert"], "0.5"),
    ("plan", "--seconds", "--budget-seconds", ["--design", "lambert:albedo=?", "--bench", "b.toml"], "0.5"),
    ("scan", "--seconds", "--budget-seconds", ["--sequential", "lambert:albedo=?", "--bench", "b.toml"], "0.5"),
    ("scan", "--adaptive", "--sequential", ["--bench", "b.toml"], "lambert:albedo=?"),
    ("serve", "--seconds", "--max-seconds", [], "0.5"),
    ("emulate", "--seconds", "--max-seconds", ["b.toml"], "0.5"),
    ("compare", "--report", "--out", ["a.csv", "b.csv"], "report"),
    ("fit", "--figure", "--plot", ["r.csv", "--model", "lambert:albedo=?"], "residuals.png"),
]

#: flags that no command takes any more (each refused where it was taken, as RENAMED says)
RETIRED = {"--seconds", "--report", "--adaptive", "--figure"}


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _live_options() -> dict[str, list[tuple[str, argparse.Action]]]:
    """Each visible option string -> the (command, action) pairs that take it."""
    out: dict[str, list[tuple[str, argparse.Action]]] = {}
    for name, sp in _subparsers().items():
        for action in sp._actions:
            if action.help == argparse.SUPPRESS or isinstance(action, argparse._HelpAction):
                continue
            for option in action.option_strings:
                out.setdefault(option, []).append((name, action))
    return out


def test_a_shared_flag_has_one_dest_and_its_declared_meaning_everywhere():
    for option, uses in _live_options().items():
        dests = {action.dest for _, action in uses}
        assert len(dests) == 1, f"{option} is stored as {sorted(dests)} by {[c for c, _ in uses]}"
        if len(uses) < 2:
            continue
        assert option in MEANINGS, (f"{option} is taken by {[c for c, _ in uses]}: declare its one meaning "
                                    "in MEANINGS (or give the second meaning its own name)")
        for command, action in uses:
            assert re.search(MEANINGS[option], action.help or ""), \
                f"bench {command} {option}: help {action.help!r} does not say {MEANINGS[option]!r}"


def test_the_walk_sees_every_command_and_catches_a_second_meaning():
    """Power: the walk covers every command of ``bench --help``, and a help text saying another
    meaning (gonio's old relative --uncertainty) fails the declared pattern."""
    from bench.cli.commands import COMMANDS

    assert set(_subparsers()) == set(COMMANDS)
    assert not re.search(MEANINGS["--uncertainty"], "relative uncertainty of each patch's BSDF (interval "
                         "half-width / value), a fraction in (0, 1)")
    assert not re.search(MEANINGS["--max-seconds"], "--design: the bench-time budget, s")


def test_retired_spellings_are_nowhere_a_live_option():
    live = _live_options()
    assert not RETIRED & set(live)
    assert {c for c, _ in live["--uncertainty"]} == {"rays", "spectro"}


@pytest.mark.parametrize("command,old,new,around,value", RENAMED, ids=[f"{c} {o}" for c, o, *_ in RENAMED])
def test_an_old_spelling_is_refused_in_one_line_naming_the_new_one(capsys, command, old, new, around, value):
    for argv in ([command, *around, old, value], [command, *around, f"{old}={value}"]):
        code, out, err = run_main(capsys, *argv)
        assert code == 2 and out == ""
        assert err.count("\n") == 1, err
        assert err.startswith(f"bench {command}: error: {old} ") and f"did you mean {new}?" in err, err


@pytest.mark.parametrize("command,old,new,around,value", RENAMED, ids=[f"{c} {n}" for c, _, n, *_ in RENAMED])
def test_the_new_spelling_is_taken(command, old, new, around, value):
    parsed = getattr(build_parser(load=[command]).parse_args([command, *around, new, value]), new[2:].replace("-", "_"))
    assert parsed == type(parsed)(value)


def test_an_abbreviation_of_an_old_spelling_is_refused_too(capsys):
    """argparse accepts unambiguous prefixes: ``--uncert`` must not slip past as something else."""
    code, _, err = run_main(capsys, "gonio", "--specimen", "lambert", "--uncert", "0.05")
    assert code == 2 and "did you mean --relative-uncertainty?" in err


def test_spectro_uncertainty_stays_absolute_and_gonio_takes_the_relative_one():
    subs = _subparsers()
    spectro = {o: a for a in subs["spectro"]._actions for o in a.option_strings}
    gonio = {o: a for a in subs["gonio"]._actions for o in a.option_strings}
    assert "absolute" in spectro["--uncertainty"].help and "relative" not in spectro["--uncertainty"].help
    assert "relative" in gonio["--relative-uncertainty"].help
