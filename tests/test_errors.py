"""One exception tree: every error ooc-dem raises for a user derives from ooc_dem.OocDemError,
which the command line catches for its one-line message and exit code 2."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import ooc_dem
from ooc_dem import cli
from ooc_dem.errors import OocDemError

# exception classes of the package that are no errors for a user, each with the reason
NOT_FOR_USERS: set[str] = set()


def exception_classes() -> dict[str, type]:
    """Every exception class defined at the top of a module of ooc_dem, by dotted name."""
    found = {}
    for info in pkgutil.walk_packages(ooc_dem.__path__, "ooc_dem."):
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            if inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == info.name:
                found[f"{info.name}.{obj.__qualname__}"] = obj
    return found


def test_every_exception_class_derives_from_the_base():
    classes = exception_classes()
    # the walk sees the layers' errors (a sample, so that an empty walk cannot pass)
    for name in (
        "ooc_dem.storage._util.StoreError",
        "ooc_dem.model.schema.ScenarioError",
        "ooc_dem.app.plan.RunError",
        "ooc_dem.app.cli_parser.CliError",
    ):
        assert name in classes, name
    outside = sorted(n for n, c in classes.items() if not issubclass(c, OocDemError) and n not in NOT_FOR_USERS)
    assert not outside, "exception classes outside the OocDemError tree:\n" + "\n".join(outside)


def test_the_second_bases_callers_catch_are_kept():
    from ooc_dem.app.runfiles import RunFileError
    from ooc_dem.model.state_check import StateError
    from ooc_dem.model.schema import ScenarioError

    assert all(issubclass(c, ValueError) for c in (ScenarioError, StateError, RunFileError))
    assert issubclass(ooc_dem.RunError, RuntimeError) and issubclass(ooc_dem.EngineError, RuntimeError)
    assert ooc_dem.OocDemError is OocDemError


@pytest.mark.parametrize(
    "error",
    [
        "ooc_dem.app.outfile.ExportError",
        "ooc_dem.app.repose.ReposeError",
        "ooc_dem.storage._util.StoreError",
        "ooc_dem.engine.memlimit.MemoryLimitError",
    ],
)
def test_the_command_line_prints_any_of_them_in_one_line_with_exit_2(error, monkeypatch, capsys):
    cls = exception_classes()[error]

    def command(args):
        raise cls("somewhere: what is wrong")

    monkeypatch.setitem(cli.COMMANDS, "check", command)
    assert cli.main(["check", "quick"]) == cli.EXIT_USAGE
    assert capsys.readouterr().err == "ooc-dem: error: somewhere: what is wrong\n"
