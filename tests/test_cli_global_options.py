"""Global options before or after every command; unknown arguments answered with the
usage of the command they followed."""

from __future__ import annotations

import pytest

from motionphysics import cli

# The commands' own parsers (built, never run): --help of each, and the options.
NAMES = list(cli.COMMANDS)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("flag", ["--quiet", "--verbose"])
def test_global_options_after_every_command(name, flag):
    parser = cli.build_parser()
    sub = cli._subparser(parser, name)
    assert flag in sub._option_string_actions, (name, flag)


@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_before_or_after_scenes(where, capsys):
    argv = ["--quiet", "scenes"] if where == "before" else ["scenes", "--quiet"]
    assert cli.main(argv) == 0
    out, err = capsys.readouterr()
    assert "builtin:" in out and err == ""


def test_global_value_survives_the_subparser():
    parser = cli.build_parser()
    args = cli.parse_args(parser, ["--quiet", "scenes"])
    assert args.quiet is True and not getattr(args, "verbose", False)
    args = cli.parse_args(parser, ["scenes", "--verbose"])
    assert args.verbose is True and not getattr(args, "quiet", False)


@pytest.mark.parametrize("name", ["scenes", "render", "fit", "init"])
def test_unknown_argument_prints_the_subcommands_usage(name, capsys):
    with pytest.raises(SystemExit) as ex:
        cli.main([name, "--no-such-flag", "x"] if name != "scenes" else [name, "--no-such-flag"])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: motionphysics {name}")
    assert f"motionphysics {name}: error:" in err


@pytest.mark.parametrize("name", ["scenes", "render", "init"])
def test_help_texts_have_no_rest_markup(name, capsys):
    with pytest.raises(SystemExit):
        cli.main([name, "--help"])
    out = capsys.readouterr().out
    for mark in ("``", ":data:", ":func:", ":class:", ":mod:", "DESIGN.md", "must not"):
        assert mark not in out, (name, mark)
