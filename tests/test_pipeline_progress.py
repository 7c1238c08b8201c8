"""Progress display: quiet in a pipe, one line per stage with --verbose, bar on a terminal."""

from __future__ import annotations

import io

import pytest

from motionphysics.progress import Progress


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_pipe_is_quiet_but_timed():
    s = io.StringIO()
    with Progress(stream=s) as p:
        with p.stage("load scene"):
            pass
        with pytest.raises(RuntimeError), p.stage("simulate", total=3) as st:
            st.advance()
            raise RuntimeError("x")
    assert s.getvalue() == ""
    assert list(p.timings) == ["load scene", "simulate"] and all(v >= 0 for v in p.timings.values())


def test_verbose_prints_one_line_per_stage():
    s = io.StringIO()
    with Progress(verbose=True, stream=s) as p, p.stage("render", total=2) as st:
        st.advance(2)
    lines = s.getvalue().splitlines()
    assert len(lines) == 1 and "render: done" in lines[0]


def test_quiet_wins_over_terminal_and_verbose():
    s = _Tty()
    with Progress(quiet=True, verbose=True, stream=s) as p, p.stage("a"):
        pass
    assert s.getvalue() == "" and not p.interactive


def test_terminal_draws_stages():
    s = _Tty()
    with Progress(stream=s) as p:
        assert p.interactive
        with p.stage("simulate", total=4) as st:
            st.note("simulate (64 substeps/frame)")
            for _ in range(4):
                st.advance()
    assert "simulate" in s.getvalue()
