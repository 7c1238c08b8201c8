"""The generated references: commands from the argparse parsers, config keys from the
pydantic config models, loss options from the ``LOSSES`` registry's ``Options`` models.

They live in ``docs/commands.md`` (block ``commands``) and ``docs/config.md`` (blocks
``config`` and ``losses``); the README links them. ``python -m motionphysics.docs_cli``
rewrites the generated blocks of those files in place (each between ``<!-- BEGIN
GENERATED: NAME ... -->`` and ``<!-- END GENERATED: NAME -->``); ``--check`` only compares
and exits 1 when a file is stale. tests/test_readme_cli.py runs the check, so a flag, a
help text, a config key, a default or a loss option cannot change without the reference
changing with it.

Everything is read from the objects the program itself uses (``cli.build_parser()``,
``config.RunConfig`` and its nested models, ``LOSSES.get(name).Options``); field
descriptions are the attribute docstrings of the models. This module must not hold any
description of its own that could drift from the code; it only formats.
"""

from __future__ import annotations

import argparse
import ast
import functools
import inspect
import re
import sys
import types
import typing
from pathlib import Path
from typing import Any

__all__ = [
    "BLOCKS",
    "command_reference",
    "config_reference",
    "field_docs",
    "help_texts",
    "iter_parsers",
    "loss_reference",
    "REFERENCE_FILES",
    "render_blocks",
    "update_file",
]

USAGE_WIDTH = 96
"""Column at which usage lines wrap (fixed, so the output does not depend on the terminal)."""


# --- shared formatting --------------------------------------------------------------------


def plain(text: str) -> str:
    """Docstring text as Markdown: reST roles and double backticks become code spans."""
    text = re.sub(r":(?:data|func|class|mod|meth|attr|obj):`~?\.?([^`]+)`", r"`\1`", text)
    text = text.replace("``", "`")
    return " ".join(text.split())


def cell(text: str) -> str:
    """Text for a Markdown table cell (pipes and angle brackets escaped, one line)."""
    text = " ".join(str(text).split())
    out, code = [], False
    for part in re.split(r"(`)", text):
        if part == "`":
            code = not code
            out.append(part)
        elif code:
            out.append(part.replace("|", "\\|"))
        else:
            out.append(part.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;"))
    return "".join(out)


def code(text: str) -> str:
    """``text`` as a code span (backticks inside are doubled-up safely)."""
    text = str(text)
    return f"`` {text} ``" if "`" in text else f"`{text}`"


# --- commands -----------------------------------------------------------------------------


def _global_flags() -> dict[str, str]:
    from motionphysics.cli import GLOBAL_OPTIONS

    return dict(GLOBAL_OPTIONS)


def iter_parsers(parser: argparse.ArgumentParser | None = None):
    """``(path, parser)`` for every command parser, depth first (``("bench", "mpm")``...)."""
    if parser is None:
        from motionphysics.cli import build_parser

        parser = build_parser()

    def walk(p, path):
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sp in action.choices.items():
                    yield (*path, name), sp
                    yield from walk(sp, (*path, name))

    yield from walk(parser, ())


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def documented_actions(p: argparse.ArgumentParser) -> list[argparse.Action]:
    """The options and positionals a command documents (not -h, not the global options,
    not the sub-command selector)."""
    glob = _global_flags()
    out = []
    for a in p._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if a.option_strings and all(s in glob for s in a.option_strings):
            continue
        out.append(a)
    return out


def usage(p: argparse.ArgumentParser) -> str:
    fmt = argparse.HelpFormatter(prog=p.prog, width=USAGE_WIDTH)
    fmt.add_usage(p.usage, p._actions, p._mutually_exclusive_groups, prefix="")
    return fmt.format_help().strip("\n")


def _invocation(p: argparse.ArgumentParser, a: argparse.Action) -> str:
    return p._get_formatter()._format_action_invocation(a)


def _help(p: argparse.ArgumentParser, a: argparse.Action) -> str:
    if not a.help:
        return ""
    return " ".join(p._get_formatter()._expand_help(a).split())


def _default(a: argparse.Action) -> str:
    d = a.default
    if d is None or d is argparse.SUPPRESS or isinstance(a, argparse._StoreTrueAction):
        return ""
    if isinstance(d, (list, tuple)):
        return code(" ".join(str(x) for x in d))
    return code(d)


def _description(p: argparse.ArgumentParser) -> str:
    paras = [" ".join(para.split()) for para in re.split(r"\n\s*\n", p.description or "")]
    return "\n\n".join(cell(para).replace("\\|", "|") for para in paras if para)


def _command_section(path: tuple[str, ...], p: argparse.ArgumentParser) -> list[str]:
    lines = [f"#### `motionphysics {' '.join(path)}`", ""]
    desc = _description(p)
    if desc:
        lines += [desc, ""]
    lines += ["```", usage(p), "```", ""]
    acts = documented_actions(p)
    if acts:
        lines += ["| argument | meaning | default |", "|---|---|---|"]
        for a in acts:
            lines.append(f"| {code(_invocation(p, a))} | {cell(_help(p, a))} | {_default(a)} |")
        lines.append("")
    subs = subcommands(p)
    if subs:
        names = ", ".join(code(f"{' '.join(path)} {n}") for n in subs)
        lines += [f"Targets: {names}.", ""]
    return lines


def command_reference(parser: argparse.ArgumentParser | None = None) -> str:
    """Markdown of every command: description, usage, a table of its arguments."""
    if parser is None:
        from motionphysics.cli import build_parser

        parser = build_parser()
    lines = [
        "Global options, accepted before or after every command:",
        "",
        "| option | meaning |",
        "|---|---|",
    ]
    for flag, text in _global_flags().items():
        lines.append(f"| {code(flag)} | {cell(text)} |")
    lines += [
        f"| `--version` | {cell(parser._option_string_actions['--version'].help or '')} |",
        "",
    ]
    for path, p in iter_parsers(parser):
        lines += _command_section(path, p)
    return "\n".join(lines).rstrip("\n")


def help_texts(parser: argparse.ArgumentParser | None = None) -> list[tuple[str, str]]:
    """``(where, text)`` of every user-facing text of the command line (descriptions,
    epilogs, argument help), for the tests that keep them free of markup."""
    if parser is None:
        from motionphysics.cli import build_parser

        parser = build_parser()
    out = [("motionphysics", parser.description or "")]
    for path, p in iter_parsers(parser):
        where = "motionphysics " + " ".join(path)
        out.append((f"{where} (description)", p.description or ""))
        out.append((f"{where} (epilog)", p.epilog or ""))
        for a in p._actions:
            if a.help and a.help is not argparse.SUPPRESS:
                name = "/".join(a.option_strings) or a.dest
                out.append((f"{where} {name}", _help(p, a)))
    # The one-line help of each command in the parent's list.
    for path, p in iter_parsers(parser):
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for choice in action._choices_actions:
                    out.append((f"motionphysics {' '.join(path)} {choice.dest}", choice.help))
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                out.append((f"motionphysics {choice.dest} (summary)", choice.help or ""))
    return [(w, t) for w, t in out if t]


# --- config models ------------------------------------------------------------------------


def field_docs(model: type) -> dict[str, str]:
    """Attribute docstrings of a pydantic model's fields, inherited ones included."""
    docs: dict[str, str] = {}
    for klass in reversed(model.__mro__):
        if klass is object or not klass.__module__.startswith("motionphysics"):
            continue
        docs.update(_module_docs(klass.__module__).get(klass.__qualname__, {}))
    return docs


@functools.cache
def _module_docs(module: str) -> dict[str, dict[str, str]]:
    """``{class qualname: {attribute: docstring}}`` of every class in ``module``'s source
    (parsed once; ``inspect.getsource`` per class is slow)."""
    try:
        src = inspect.getsource(sys.modules[module])
    except (KeyError, OSError, TypeError):
        return {}
    out: dict[str, dict[str, str]] = {}

    def walk(body, prefix):
        for node in body:
            if isinstance(node, ast.ClassDef):
                qual = f"{prefix}{node.name}"
                out[qual] = _attribute_docs(node.body)
                walk(node.body, qual + ".")
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                walk(node.body, f"{prefix}{node.name}.<locals>.")

    walk(ast.parse(src).body, "")
    return out


def _attribute_docs(body) -> dict[str, str]:
    docs = {}
    for stmt, nxt in zip(body, [*body[1:], None], strict=True):
        if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
            continue
        if (
            isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[stmt.target.id] = inspect.cleandoc(nxt.value.value)
    return docs


_UNIT = re.compile(r"\[([^\[\],]+)\]")
_UNIT_OK = re.compile(r"^(?:[A-Za-z]+(?:[/^.* ]?[A-Za-z0-9^]+)*|-)$")


def unit_of(doc: str) -> str:
    """The unit in square brackets of a field docstring (``[m/s]``), '' when none. Brackets
    inside code (``{duck: [E]}``) are examples, not units."""
    doc = re.sub(r"``.*?``|`[^`]*`", "", doc, flags=re.S)
    for m in _UNIT.finditer(doc):
        u = m.group(1).strip()
        if _UNIT_OK.match(u) and not u.isdigit():
            return u
    return ""


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Annotated:
        return _type_name(args[0])
    if tp is type(None):
        return "null"
    if origin is typing.Literal:
        return " | ".join(str(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in args)
    if origin is tuple:
        if args == (float, float, float):
            return "3 numbers"
        if len(args) == 2 and all(_type_name(a) == "3 numbers" for a in args):
            return "box [[xmin, ymin, zmin], [xmax, ymax, zmax]]"
        if len(args) == 2 and _type_name(args[0]) == "3 numbers" and args[1] is float:
            return "sphere [[x, y, z], r]"
        if len(set(args)) == 1 and args[0] in (float, int, bool):
            kind = {float: "numbers", int: "integers", bool: "booleans"}[args[0]]
            return f"{len(args)} {kind}"
        return "[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is list:
        inner = _type_name(args[0]) if args else "any"
        if args and typing.get_origin(args[0]) is typing.Annotated:
            inner = "entry"
        return f"list of {inner}"
    if origin is dict:
        return "mapping"
    if isinstance(tp, type):
        from pydantic import BaseModel

        if issubclass(tp, BaseModel):
            return "mapping"
        return {"float": "float", "int": "int", "str": "str", "bool": "bool"}.get(
            tp.__name__, tp.__name__
        )
    return str(tp)


def _bounds(field) -> str:
    ops = {"gt": ">", "ge": "≥", "lt": "<", "le": "≤"}
    parts = []
    for m in field.metadata:
        for attr, sym in ops.items():
            v = getattr(m, attr, None)
            if v is not None:
                parts.append(f"{sym} {v:g}" if isinstance(v, float) else f"{sym} {v}")
    return ", ".join(parts)


def _default_text(field) -> str:
    if field.is_required():
        return "required"
    d = field.get_default(call_default_factory=True)
    if d is None:
        return "`null`"
    if isinstance(d, bool):
        return code(str(d).lower())
    if isinstance(d, float):
        return code(f"{d:g}")
    if isinstance(d, tuple):

        def fmt(x):
            if isinstance(x, tuple):
                return "[" + ", ".join(fmt(y) for y in x) + "]"
            if isinstance(x, bool):
                return str(x).lower()
            return f"{x:g}" if isinstance(x, float) else str(x)

        return code(fmt(d))
    if isinstance(d, (list, dict)) and not d:
        return code("[]" if isinstance(d, list) else "{}")
    if hasattr(d, "model_dump"):
        return ""
    return code(d)


def model_table(model: type, prefix: str = "", skip: tuple[str, ...] = ("type",)) -> list[str]:
    """A Markdown table of a model's keys: key, type (with bounds), default, unit, meaning."""
    docs = field_docs(model)
    rows = ["| key | type | default | unit | meaning |", "|---|---|---|---|---|"]
    for name, f in model.model_fields.items():
        if name in skip:
            continue
        key = f.alias or name
        doc = docs.get(name, "")
        tp = _type_name(f.annotation)
        b = _bounds(f)
        tp = f"{tp} ({b})" if b else tp
        unit = unit_of(doc)
        rows.append(
            f"| {code(prefix + key)} | {cell(tp)} | {_default_text(f)} | {cell(unit)} "
            f"| {cell(plain(doc))} |"
        )
    return rows


def _union_members(tp: Any) -> list[type]:
    while typing.get_origin(tp) is typing.Annotated:
        tp = typing.get_args(tp)[0]
    if typing.get_origin(tp) is list:
        return _union_members(typing.get_args(tp)[0])
    return [a for a in typing.get_args(tp) if isinstance(a, type)]


def _tag(model: type) -> str:
    return typing.get_args(model.model_fields["type"].annotation)[0]


def config_reference() -> str:
    """Markdown tables of every run-config section, generated from ``config.RunConfig``."""
    from motionphysics.config import RunConfig

    lines: list[str] = []
    top = RunConfig.model_fields
    top_docs = field_docs(RunConfig)
    scalars = [
        n
        for n, f in top.items()
        if not _is_section(f.annotation) and not _is_list_of_kinds(_no_none(f.annotation))
    ]
    for name, f in top.items():
        ann = f.annotation
        if _is_list_of_kinds(_no_none(ann)):
            lines += [f"#### `{name}` (a list; each entry's `type` picks one kind)", ""]
            if top_docs.get(name):
                lines += [plain(top_docs[name]), ""]
            for m in _union_members(_no_none(ann)):
                doc = plain(inspect.getdoc(m) or "") if m.__doc__ else ""
                lines += [f"`{{type: {_tag(m)}}}`" + (f": {cell(doc)}" if doc else ""), ""]
                lines += model_table(m)
                lines.append("")
        elif _is_section(ann):
            model = ann
            lines += [f"#### `{name}`", ""]
            doc = model.__doc__ and inspect.getdoc(model)
            if doc and not doc.startswith(model.__name__):
                lines += [plain(doc), ""]
            lines += model_table(model, prefix=f"{name}.")
            lines.append("")
    lines += ["#### top level", ""]
    lines += model_table(_subset(RunConfig, scalars))
    return "\n".join(lines).rstrip("\n")


def _no_none(ann: Any) -> Any:
    """``X`` of an annotation ``X | None`` (else the annotation itself)."""
    if typing.get_origin(ann) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(ann) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return ann


def _is_list_of_kinds(ann: Any) -> bool:
    return typing.get_origin(ann) is list and bool(_union_members(ann))


def _is_section(ann: Any) -> bool:
    from pydantic import BaseModel

    return isinstance(ann, type) and issubclass(ann, BaseModel)


def _subset(model: type, names: list[str]):
    """A view of ``model`` with only ``names`` (for the top-level table)."""
    return _ViewModel(model, names)


class _ViewModel:
    def __init__(self, model, names):
        self.__mro__ = model.__mro__
        self.model_fields = {n: model.model_fields[n] for n in names}


# --- losses -------------------------------------------------------------------------------


def _loss_summary(cls) -> str:
    mod = sys.modules[cls.__module__]
    first = (inspect.getdoc(mod) or inspect.getdoc(cls) or "").split("\n\n")[0]
    first = re.sub(r"^``\w+``:\s*", "", first.strip())
    return plain(first)


def loss_reference() -> str:
    """Markdown: every registered loss, what it needs, and its options (from ``Options``)."""
    from motionphysics.losses import LOSSES

    lines = [
        "| loss | needs | what it is |",
        "|---|---|---|",
    ]
    classes = {name: LOSSES.get(name) for name in LOSSES.names()}
    for name, cls in classes.items():
        needs = [
            w
            for w, flag in (
                ("a prior", "needs_prior"),
                ("rendered frames", "needs_render"),
                ("particle states", "needs_states"),
            )
            if getattr(cls, flag, False)
        ]
        lines.append(f"| {code(name)} | {cell(', '.join(needs))} | {cell(_loss_summary(cls))} |")
    lines.append("")
    for name, cls in classes.items():
        opts = getattr(cls, "Options", None)
        lines.append(f"#### `{{type: {name}}}` options")
        lines.append("")
        if opts is None or not opts.model_fields:
            lines += ["No options besides `weight`.", ""]
            continue
        lines += model_table(opts, skip=())
        lines.append("")
    return "\n".join(lines).rstrip("\n")


# --- reference blocks ---------------------------------------------------------------------

BLOCKS = {
    "commands": command_reference,
    "config": config_reference,
    "losses": loss_reference,
}
"""Generated reference blocks by name (the name in the BEGIN/END markers)."""

REFERENCE_FILES = {
    "docs/commands.md": ("commands",),
    "docs/config.md": ("config", "losses"),
}
"""The files that hold the generated blocks (relative to the repository root), and which."""

_BLOCK = re.compile(
    r"(<!-- BEGIN GENERATED: (?P<name>\w+)[^>]*-->)\n(?P<body>.*?)\n?(<!-- END GENERATED: (?P=name) -->)",
    re.S,
)


def render_blocks(text: str, names: list[str] | None = None) -> str:
    """``text`` with each generated block replaced by a fresh rendering."""
    cache: dict[str, str] = {}

    def sub(m: re.Match) -> str:
        name = m.group("name")
        if name not in BLOCKS or (names is not None and name not in names):
            return m.group(0)
        if name not in cache:
            cache[name] = BLOCKS[name]()
        return f"{m.group(1)}\n\n{cache[name]}\n\n{m.group(4)}"

    return _BLOCK.sub(sub, text)


def block_names(text: str) -> list[str]:
    return [m.group("name") for m in _BLOCK.finditer(text)]


def update_file(path: str | Path, check: bool = False) -> bool:
    """Rewrite the generated blocks of ``path``; True when it was already current."""
    p = Path(path)
    old = p.read_text(encoding="utf-8")
    new = render_blocks(old)
    if new != old and not check:
        p.write_text(new, encoding="utf-8")
    return new == old


def _repo_root() -> Path:
    """The repository holding this checkout (the folder with pyproject.toml and docs/)."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "pyproject.toml").is_file() and (parent / "docs").is_dir():
            return parent
    return Path.cwd()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m motionphysics.docs_cli",
        description="Regenerate the command, config and loss references "
        f"({', '.join(REFERENCE_FILES)}).",
    )
    ap.add_argument(
        "files", nargs="*", help="files to update (default: the reference files of the repository)"
    )
    ap.add_argument("--check", action="store_true", help="exit 1 if a file is out of date")
    args = ap.parse_args(argv)
    files = args.files or [str(_repo_root() / f) for f in REFERENCE_FILES]
    stale = [f for f in files if not update_file(f, check=args.check)]
    if args.check and stale:
        for f in stale:
            print(f"{f}: generated blocks are stale; run python -m motionphysics.docs_cli")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
