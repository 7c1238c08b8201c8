"""The references and --help say the same thing, help texts are written for users, and no
file of the repository points at a file the repository does not have.

The command, config and loss references (docs/commands.md, docs/config.md, linked from the
README) are generated (motionphysics.docs_cli) from the parsers, the config models and the
losses' Options models; the first test fails when they are stale. The flag tests read the
documents independently of the generator, so a hand-written example that names a flag a
command does not have fails too.
"""

from __future__ import annotations

import argparse
import difflib
import re
import subprocess
from pathlib import Path

import pytest

from motionphysics import docs_cli
from motionphysics.cli import GLOBAL_OPTIONS, build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
COMMANDS = ROOT / "docs" / "commands.md"
CONFIG = ROOT / "docs" / "config.md"
FIX = "run `python -m motionphysics.docs_cli` to regenerate docs/commands.md and docs/config.md"


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    return build_parser()


@pytest.fixture(scope="module")
def parsers(parser) -> dict[tuple[str, ...], argparse.ArgumentParser]:
    return dict(docs_cli.iter_parsers(parser))


def readme() -> str:
    return README.read_text(encoding="utf-8")


def commands_doc() -> str:
    return COMMANDS.read_text(encoding="utf-8")


def config_doc() -> str:
    return CONFIG.read_text(encoding="utf-8")


def section(text: str, heading: str) -> str:
    """The text of the level-2 section ``## heading`` (up to the next level-2 heading)."""
    m = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert m, f"no '## {heading}' section"
    return m.group(1)


def flags_of(p: argparse.ArgumentParser) -> set[str]:
    return {s for a in p._actions for s in a.option_strings if s not in ("-h", "--help")}


GLOBAL = {flag for flag, _ in GLOBAL_OPTIONS}


# --- generated blocks ---------------------------------------------------------------------


def test_generated_blocks_are_current():
    seen = []
    for name, blocks in docs_cli.REFERENCE_FILES.items():
        text = (ROOT / name).read_text(encoding="utf-8")
        names = docs_cli.block_names(text)
        assert sorted(names) == sorted(blocks), (name, names)
        seen += names
        fresh = docs_cli.render_blocks(text)
        if fresh != text:
            diff = "\n".join(
                list(difflib.unified_diff(text.splitlines(), fresh.splitlines(), lineterm=""))[:40]
            )
            pytest.fail(f"{name} is stale; {FIX}\n{diff}")
    assert sorted(seen) == sorted(docs_cli.BLOCKS), seen
    # The README holds no generated block (it links the references instead).
    assert docs_cli.block_names(readme()) == []


def test_the_readme_links_the_generated_references():
    links = set(re.findall(r"\]\(([^)\s#]+)", readme()))
    for name in docs_cli.REFERENCE_FILES:
        assert name in links, f"README.md does not link {name}"


def test_readme_starts_with_make_demo_and_make_test():
    commands = re.findall(r"^(make \w+)", readme(), re.M)
    assert commands[:2] == ["make demo", "make test"], commands[:4]


# --- every flag in both -------------------------------------------------------------------


def command_sections(text: str) -> dict[tuple[str, ...], str]:
    """``{("run",): text, ("bench", "mpm"): text, ...}`` of docs/commands.md's reference."""
    body = section(text, "Command reference")
    parts = re.split(r"^#### `motionphysics ([^`]+)`\n", body, flags=re.M)
    return {tuple(parts[i].split()): parts[i + 1] for i in range(1, len(parts), 2)}


def test_every_command_has_a_readme_section_and_back(parsers):
    documented = command_sections(commands_doc())
    assert set(documented) == set(parsers), (
        f"in parsers, not docs/commands.md: {sorted(set(parsers) - set(documented))}; "
        f"in docs/commands.md, not parsers: {sorted(set(documented) - set(parsers))}; {FIX}"
    )


def test_every_flag_of_a_command_is_in_its_readme_section_and_back(parsers):
    documented = command_sections(commands_doc())
    for path, p in parsers.items():
        text = documented.get(path, "")
        named = set(re.findall(r"(?<![\w-])(--[a-z][\w-]*)", text))
        flags = flags_of(p)
        missing = {f for f in flags - named if f not in GLOBAL}
        assert not missing, (
            f"motionphysics {' '.join(path)}: {sorted(missing)} not in docs/commands.md; {FIX}"
        )
        # A command's description may name its sub-commands' flags (bench: --json).
        below = {f for q, sp in parsers.items() if q[: len(path)] == path for f in flags_of(sp)}
        extra = named - flags - below - GLOBAL
        assert not extra, (
            f"docs/commands.md names {sorted(extra)} for motionphysics {' '.join(path)}"
        )


def test_every_positional_is_in_its_readme_section(parsers):
    documented = command_sections(commands_doc())
    for path, p in parsers.items():
        for a in p._actions:
            if a.option_strings or isinstance(a, argparse._SubParsersAction):
                continue
            name = a.metavar or a.dest
            assert f"`{name}`" in documented[path], (path, name)


INVOCATION = re.compile(r"motionphysics ((?:[a-z]+)(?: [a-z]+)?)((?: +[^\s`|]+)*)")


def invocations(text: str):
    """``(command words, argument text)`` of every ``motionphysics CMD ...`` in code."""
    spans = re.findall(r"```.*?```", text, re.S) + re.findall(r"`[^`\n]+`", text)
    for span in spans:
        for line in span.splitlines():
            for m in INVOCATION.finditer(line):
                yield m.group(1).split(), m.group(2)


DOCS_WITH_EXAMPLES = [
    "README.md",
    "examples/README.md",
    *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md")),
]


@pytest.mark.parametrize("name", DOCS_WITH_EXAMPLES)
def test_examples_in_the_docs_use_real_flags(name, parsers):
    """``motionphysics run ... --flag`` anywhere in the docs names a flag ``run`` has."""
    path = ROOT / name
    if not path.is_file():
        pytest.skip(f"{name} not in this checkout")
    seen = 0
    for words, rest in invocations(path.read_text(encoding="utf-8")):
        key = tuple(words) if tuple(words) in parsers else tuple(words[:1])
        if key not in parsers:
            continue  # prose such as "motionphysics is ..." or `motionphysics[viewer]`
        seen += 1
        allowed = flags_of(parsers[key]) | GLOBAL
        for flag in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", rest):
            assert flag in allowed, f"{name}: motionphysics {' '.join(key)} has no {flag}"
    if name == "docs/commands.md":
        assert seen > 20, seen  # the check looked at the command reference


# --- help texts for users -----------------------------------------------------------------

MARKUP = [
    (re.compile(r"``"), "reST literal ``...``"),
    (re.compile(r":(?:data|func|class|mod|meth|attr|obj|ref|doc):`"), "reST role"),
    (re.compile(r"`[^`]+`_"), "reST link"),
    (re.compile(r"\bthis module\b", re.I), "internal note (this module)"),
    (re.compile(r"\bmust not\b", re.I), "internal note (must not)"),
    (re.compile(r"\bmotionphysics\.[a-z_]+\.[a-z_]"), "internal module path"),
    (re.compile(r"\b(?:register_target|subparsers?|set_defaults)\b"), "argparse internals"),
    (re.compile(r"\b(?:TODO|FIXME|XXX)\b"), "unfinished note"),
    (re.compile(r"DESIGN\.md"), "a file the repository does not have"),
]


CONSTANT = re.compile(r"\b[A-Z][A-Z0-9]*_[A-Z0-9_]+\b")


def test_help_texts_are_written_for_users(parser, parsers):
    metavars = set()
    for p in parsers.values():
        for a in p._actions:
            mv = a.metavar if isinstance(a.metavar, tuple) else (a.metavar,)
            metavars |= {m for m in mv if m}
    bad = []
    for where, text in docs_cli.help_texts(parser):
        for pattern, what in MARKUP:
            m = pattern.search(text)
            if m:
                bad.append(f"{where}: {what}: {m.group(0)!r}")
        for name in CONSTANT.findall(text):
            # A metavar (RUN_DIR) or an environment variable is for users; a constant
            # of the code (BENCH_TARGETS) is not.
            if name not in metavars and not name.startswith(("MOTIONPHYSICS_", "OPENAI_")):
                bad.append(f"{where}: internal constant name: {name!r}")
    assert not bad, "\n".join(bad)


def test_markup_check_catches_what_it_should():
    # The patterns above, on texts that the bench help once held.
    samples = [
        "Each target lives in a module listed in :data:`BENCH_TARGETS`",
        "This module must not change the solver",
        "``motionphysics run CONFIG``: the main job",
        "the library is motionphysics.optimize.fit",
    ]
    for s in samples:
        assert any(p.search(s) for p, _ in MARKUP) or CONSTANT.search(s), s
    assert not any(
        p.search("--out DIR: run directory (default: runs/<config name>)") for p, _ in MARKUP
    )


def test_every_argument_has_help(parsers):
    missing = [
        f"motionphysics {' '.join(path)} {'/'.join(a.option_strings) or a.dest}"
        for path, p in parsers.items()
        for a in docs_cli.documented_actions(p)
        if not a.help
    ]
    assert not missing, missing


def test_every_command_says_what_it_does(parsers):
    assert all(p.description for p in parsers.values()), [
        path for path, p in parsers.items() if not p.description
    ]


# --- config and loss references -----------------------------------------------------------


def config_models():
    from pydantic import BaseModel

    from motionphysics.config import RunConfig

    seen, todo = [], [RunConfig]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.append(m)
        for f in m.model_fields.values():
            for tp in _types_in(f.annotation):
                if isinstance(tp, type) and issubclass(tp, BaseModel):
                    todo.append(tp)
    return seen


def _types_in(tp):
    import typing

    yield tp
    for a in typing.get_args(tp):
        yield from _types_in(a)


def test_every_config_key_and_loss_option_is_described():
    from motionphysics.losses import LOSSES

    models = config_models() + [
        LOSSES.get(n).Options for n in LOSSES.names() if getattr(LOSSES.get(n), "Options", None)
    ]
    missing = []
    for m in models:
        docs = docs_cli.field_docs(m)
        missing += [
            f"{m.__qualname__}.{n}"
            for n, f in m.model_fields.items()
            if n != "type" and n not in docs and not _is_section_field(f.annotation)
        ]
    # LossSpec's own keys (type, weight) are described in the README's losses text.
    missing = [x for x in missing if not x.startswith("LossSpec.")]
    assert not missing, f"add an attribute docstring to {missing}"


def _is_section_field(ann) -> bool:
    # Sections (scene, sim, ...) and lists of kinds (forces) are the tables' headings.
    from pydantic import BaseModel

    return any(isinstance(t, type) and issubclass(t, BaseModel) for t in _types_in(ann))


def test_units_and_defaults_of_the_boundary_and_force_tables():
    """Spot checks against the physics (not the generator): a few values a person relies on."""
    text = section(config_doc(), "Keys, types, defaults and units")
    rows = {
        (r.split("|")[1].strip(), r.split("|")[3].strip(), r.split("|")[4].strip())
        for r in text.splitlines()
        if r.startswith("| `")
    }
    assert ("`force`", "required", "m/s^2") in rows  # add_constant_force: an acceleration
    assert ("`force`", "required", "m/s") in rows  # add_impulse: a velocity change
    assert ("`angular_velocity`", "required", "rad/s") in rows
    assert ("`sim.gravity`", "`[0, 0, -9.8]`", "m/s^2") in rows
    assert ("`sim.frame_dt`", "`0.04`", "s") in rows
    assert ("`friction`", "`0`", "") in rows  # bounding_box: slip walls unless asked


def test_unit_extraction():
    assert docs_cli.unit_of("Gravity [m/s^2]; the world is z-up.") == "m/s^2"
    assert docs_cli.unit_of("RGB in [0, 1].") == ""
    assert docs_cli.unit_of("``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` [m]; null") == "m"
    assert docs_cli.unit_of("Viscosity [Pa s] (fluids).") == "Pa s"
    assert docs_cli.unit_of("Poisson's ratio [-].") == "-"
    assert docs_cli.unit_of("a mapping by object name (``{duck: [E], block: [E, nu]}``)") == ""


def test_loss_table_lists_every_registered_loss():
    from motionphysics.losses import LOSSES

    text = section(config_doc(), "Losses")
    for name in LOSSES.names():
        assert f"`{{type: {name}}}` options" in text, name


def test_check_mode_reports_a_stale_reference(tmp_path):
    stale = tmp_path / "commands.md"
    end = "\n<!-- END GENERATED: commands -->"
    text = commands_doc().replace(end, "\n| `--no-such-flag` | stale row |" + end, 1)
    assert text != commands_doc()
    stale.write_text(text, encoding="utf-8")
    assert docs_cli.main([str(stale), "--check"]) == 1
    assert stale.read_text(encoding="utf-8") == text  # --check never writes
    assert docs_cli.main([str(stale)]) == 0
    assert stale.read_text(encoding="utf-8") == commands_doc()
    # Without a file, every reference of the repository is checked (and is current).
    assert docs_cli.main(["--check"]) == 0


# --- no references to files the repository does not have -----------------------------------

SCANNED = ("src", "docs", "examples", "README.md")
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".html", ".cfg", ".json"}
OUTPUT_FILES = {"compare.md"}
"""Markdown files the program writes into an output folder (not repository files)."""
TOP_DIRS = ("examples", "docs", "tests", "benchmarks", "src", "tools")


def repo_files() -> list[Path]:
    try:
        out = subprocess.run(
            ["git", "ls-files", "--cached", "--others", "--exclude-standard", *SCANNED],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split()
        files = [ROOT / f for f in out]
    except (OSError, subprocess.CalledProcessError):
        files = [
            p for s in SCANNED for p in ([ROOT / s] if s.endswith(".md") else (ROOT / s).rglob("*"))
        ]
    return [f for f in files if f.is_file() and f.suffix in TEXT_SUFFIXES]


def all_names() -> set[str]:
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    ).stdout.split()
    return {Path(f).name for f in out} or {p.name for p in ROOT.rglob("*") if p.is_file()}


PLACEHOLDERS = ("NAME", "FILE", "DIR", "PATH", "OUT", "CONFIG", "SCENE", "RUN_DIR", "YOUR")


def _placeholder(ref: str) -> bool:
    # examples/NAME.yaml, DIR/compare.md, tests/sim/test_physics_*.py, runs/<name>
    words = "|".join(PLACEHOLDERS)
    return bool(re.search(rf"(^|/)(?:{words})(\.|/|$)|[*<>{{}}]", ref))


def _exists(ref: str, where: Path) -> bool:
    ref = ref.rstrip("/.,;:)")
    if any(ch in ref for ch in "*?"):
        return any(ROOT.glob(ref))
    return (where.parent / ref).exists() or (ROOT / ref).exists()


def broken_references(path: Path, names: set[str]) -> list[str]:
    text = path.read_text(encoding="utf-8", errors="replace")
    bad = []
    # Markdown links to local files.
    if path.suffix == ".md":
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:|#", target):
                continue
            if not _exists(target.split("#")[0], path):
                bad.append(target)
    # Any *.md named anywhere: a document of the repository (or an output file).
    for ref in re.findall(r"(?<![\w./-])([\w./-]*[A-Za-z0-9_-]\.md)\b", text):
        base = Path(ref).name
        if base in OUTPUT_FILES or _placeholder(ref):
            continue
        if "/" not in ref and base in names:
            continue
        if not _exists(ref, path):
            bad.append(ref)
    # Paths into the repository's top-level folders.
    for ref in re.findall(rf"(?<![\w./-])((?:{'|'.join(TOP_DIRS)})/[\w./*-]+)", text):
        ref = ref.rstrip(".,;:")
        if _placeholder(ref) and "*" not in ref:
            continue
        if not _exists(ref, path):
            bad.append(ref)
    return bad


def test_no_reference_to_a_file_the_repository_does_not_have():
    names = all_names()
    bad = {}
    for f in repo_files():
        refs = broken_references(f, names)
        if refs:
            bad[str(f.relative_to(ROOT))] = sorted(set(refs))
    assert not bad, f"references to files not in the repository: {bad}"


def test_reference_check_catches_a_missing_file(tmp_path):
    names = all_names()
    doc = tmp_path / "x.md"
    doc.write_text(
        "See DESIGN.md, [the notes](notes/missing.md), `examples/no_such.yaml` and "
        "research/priors-brief.md; docs/CONTRACTS.md, examples/NAME.yaml and DIR/compare.md are fine."
    )
    bad = broken_references(doc, names)
    assert set(bad) == {
        "DESIGN.md",
        "notes/missing.md",
        "examples/no_such.yaml",
        "research/priors-brief.md",
    }, bad


def test_the_config_reference_example_loads(tmp_path):
    """docs/config.md's YAML example is a valid run config (keys, values, plug-ins)."""
    from motionphysics.runconfig import load_run_config

    m = re.search(r"```yaml\n(.*?)```", config_doc(), re.S)
    assert m, "docs/config.md has a YAML example"
    path = tmp_path / "example.yaml"
    path.write_text(m.group(1), encoding="utf-8")
    cfg = load_run_config(str(path), {})
    assert cfg.material.class_ == "elastic" and cfg.optimize.loss_specs()[0].type == "lmd"
