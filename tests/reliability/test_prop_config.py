"""Property: any mutation of a run config ends in a config or ONE line naming the file.

Library level (``config_from_dict`` / ``load_config``) with many cases, and the CLI
(``simulate``) on the broken ones: status 2, one stderr line, no traceback, and no
output directory created.
"""

from __future__ import annotations

import copy
import math

import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from reliability_cases import CASES, OUTCOMES, examples

from motionphysics.config import config_from_dict, load_config
from motionphysics.errors import UserInputError

BASE = {
    "scene": {"source": "builtin:sphere", "scale": 0.3, "translate": [0, 0, 0.3]},
    "prompt": "A rubber ball is dropped onto the ground and bounces back.",
    "material": {"class": "elastic", "E": 2.0e7, "nu": 0.4, "density": 1100},
    "sim": {"grid": 16, "frames": 4, "frame_dt": 0.04, "substeps": "auto"},
    "boundary_conditions": [
        {"type": "surface_collider", "point": [0, 0, 0], "normal": [0, 0, 1], "mode": "sticky"},
        {"type": "bounding_box"},
    ],
    "forces": [{"type": "add_impulse", "force": [0, 0, 5], "end": 0.01}],
    "camera": {"width": 64, "height": 48, "fov": 45.0},
    "optimize": {"prior": "none", "iterations": 2, "lr": 0.05},
}

LEAVES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["auto", "elastik", "glue", "sticky", "lots", "", "1e400", "-0"]),
    st.lists(st.floats(-10, 10), max_size=7),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


def _get(node, path):
    for p in path:
        node = node[p]
    return node


@st.composite
def mutated(draw):
    cfg = copy.deepcopy(BASE)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(cfg) if p]
        path = draw(st.sampled_from(paths))
        parent = _get(cfg, path[:-1])
        key = path[-1]
        action = draw(st.sampled_from(["replace", "delete", "typo", "extra"]))
        if action == "replace":
            parent[key] = draw(LEAVES)
        elif action == "delete":
            del parent[key]
        elif action == "typo" and isinstance(key, str):
            new = key[:-1] if len(key) > 1 and draw(st.booleans()) else key + "s"
            parent[new] = parent.pop(key)
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(LEAVES)
    return cfg


def _check_one_line(msg: str, origin: str):
    assert msg.isprintable() and msg.startswith(origin + ": "), repr(msg)
    assert "Traceback" not in msg and len(msg) < 400, msg


@settings(max_examples=examples(150), deadline=None, suppress_health_check=list(HealthCheck))
@given(mutated())
def test_config_mutations_validate_or_one_line(cfg):
    CASES["config: mutated mapping (config_from_dict)"] += 1
    try:
        config_from_dict(cfg, "cfg.yaml")
        OUTCOMES["config: valid"] += 1
    except UserInputError as err:
        OUTCOMES["config: one-line error"] += 1
        _check_one_line(str(err), "cfg.yaml")


@settings(max_examples=examples(80), deadline=None, suppress_health_check=list(HealthCheck))
@given(st.data())
def test_yaml_text_mutations(tmp_path_factory, data):
    CASES["config: mutated YAML text (load_config)"] += 1
    text = yaml.safe_dump(BASE, sort_keys=False)
    pos = data.draw(st.integers(0, len(text)))
    junk = data.draw(st.sampled_from(["", ":", "- ", "\t", "{", "]", "'", "&a", "*b", "\x00", "é"]))
    cut = data.draw(st.booleans())
    text = text[:pos] + junk + ("" if cut else text[pos:])
    path = tmp_path_factory.mktemp("y") / "c.yaml"
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        load_config(path)
    except UserInputError as err:
        _check_one_line(str(err), str(path))


@settings(max_examples=examples(15), deadline=None, suppress_health_check=list(HealthCheck))
@given(mutated())
def test_cli_refuses_broken_configs_in_one_line(tmp_path_factory, cfg):
    try:
        config_from_dict(cfg, "x")
        valid = True
    except UserInputError:
        valid = False
    assume(not valid)  # a valid one would run a whole simulation
    CASES["config: broken config through `simulate` (CLI)"] += 1
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from motionphysics.cli import main

    d = tmp_path_factory.mktemp("cli")
    path = d / "broken.yaml"
    path.write_text(yaml.safe_dump(_jsonable(cfg), sort_keys=False))
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(["simulate", str(path), "--out", str(d / "run")])
    lines = err.getvalue().strip().splitlines()
    assert rc == 2 and len(lines) == 1, err.getvalue()
    assert "broken.yaml" in lines[0] and "Traceback" not in err.getvalue()
    assert not (d / "run").exists()


def _jsonable(x):
    if isinstance(x, float) and not math.isfinite(x):
        return x  # yaml writes .nan / .inf
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_jsonable(v) for v in x]
    return x
