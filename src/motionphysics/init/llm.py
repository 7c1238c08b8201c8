"""The ``llm`` and ``naive`` init backends: an OpenAI-compatible Chat Completions client.

Any server speaking the Chat Completions API works (OpenAI GPT-4-class models,
Ollama, vLLM, llama.cpp ``server``): base URL, model and key come from
:class:`LLMOptions`, else from the environment (``MOTIONPHYSICS_LLM_BASE_URL``,
``MOTIONPHYSICS_LLM_MODEL``, ``MOTIONPHYSICS_LLM_API_KEY`` or ``OPENAI_API_KEY``).
The key is passed to the client only: it is never logged, printed, stored in an
estimate or written to a run directory.

Flow of one estimate: ask (the paper's ranged template, or PhysFlow's naive one);
parse the answer robustly (code fences, text around the JSON, numbers given as
strings, key spellings); validate against the catalogue. An unusable answer
(no JSON, unknown class, missing or non-numeric parameters) is re-asked ONCE with
the validation error; a second unusable answer is an :class:`LLMError`. Values
outside their range are clamped and recorded, never re-asked. Timeouts and
transient HTTP errors are retried by the client with exponential backoff
(``max_retries``).
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field, replace
from typing import Any

from motionphysics.errors import UserInputError
from motionphysics.init.prompt import build_messages, repair_message
from motionphysics.materials.catalog import (
    MATERIALS,
    Clamp,
    MaterialParams,
    normalise_class,
    validate,
)

__all__ = ["LLMOptions", "LLMError", "LLMAnswer", "ask_material", "parse_answer"]

DEFAULT_MODEL = "gpt-4o"


class LLMError(UserInputError):
    """The LLM backend could not produce a usable answer (server, model or answer problem)."""


@dataclass(frozen=True)
class LLMOptions:
    """Where and how to ask. ``None`` fields are read from the environment by :meth:`resolved`."""

    base_url: str | None = None
    """Chat Completions base URL, e.g. ``http://localhost:11434/v1`` (Ollama); None: OpenAI."""
    model: str | None = None
    """Model name; None: ``$MOTIONPHYSICS_LLM_MODEL`` or ``gpt-4o``."""
    api_key: str | None = field(default=None, repr=False)
    """Secret; None: ``$MOTIONPHYSICS_LLM_API_KEY`` or ``$OPENAI_API_KEY``. Never logged."""
    timeout: float = 60.0
    """Seconds per request."""
    max_retries: int = 2
    """Retries of timeouts / connection errors / 429 / 5xx, with exponential backoff."""
    temperature: float = 0.0

    def resolved(self) -> LLMOptions:
        env = os.environ
        base_url = self.base_url or env.get("MOTIONPHYSICS_LLM_BASE_URL") or None
        model = self.model or env.get("MOTIONPHYSICS_LLM_MODEL") or DEFAULT_MODEL
        key = self.api_key or env.get("MOTIONPHYSICS_LLM_API_KEY") or env.get("OPENAI_API_KEY")
        if not (self.timeout > 0 and math.isfinite(self.timeout)):
            raise UserInputError(
                f"--timeout: expected a positive number of seconds, got {self.timeout!r}"
            )
        if key is None:
            if base_url is None:
                raise UserInputError(
                    "llm backend: no API key (set OPENAI_API_KEY or MOTIONPHYSICS_LLM_API_KEY), "
                    "or point --base-url / MOTIONPHYSICS_LLM_BASE_URL at a local server"
                )
            key = "not-needed"  # local servers (Ollama, vLLM, llama.cpp) ignore the key
        return replace(self, base_url=base_url, model=model, api_key=key)


@dataclass(frozen=True)
class LLMAnswer:
    """A validated answer: the material, its clamps, and every raw reply text received."""

    params: MaterialParams
    clamped: list[Clamp]
    raw_answers: list[str]
    ignored: list[str]
    """Keys of the answer that do not belong to the class (kept only in the raw text)."""


# --- parsing --------------------------------------------------------------------------

_KEY_ALIASES = {
    "material_type": "class",
    "material": "class",
    "materialtype": "class",
    "class": "class",
    "type": "class",
    "material_class": "class",
    "density": "density",
    "rho": "density",
    "e": "E",
    "youngs_modulus": "E",
    "young_modulus": "E",
    "young's_modulus": "E",
    "nu": "nu",
    "poisson_ratio": "nu",
    "poissons_ratio": "nu",
    "poisson's_ratio": "nu",
    "tau_y": "tau_Y",
    "yield_stress": "tau_Y",
    "tau": "tau_Y",
    "sigma_y": "tau_Y",
    "eta": "eta",
    "plastic_viscosity": "eta",
    "theta_fric": "theta_fric",
    "friction_angle": "theta_fric",
    "theta": "theta_fric",
    "mu": "mu",
    "viscosity": "mu",
    "kappa": "kappa",
    "bulk_modulus": "kappa",
    "k": "kappa",
    "n": "n",
    "power_index": "n",
    "flow_index": "n",
    "power_law_index": "n",
}

_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)```", re.S)
# A number given as a string: "7850", "2.1e11", "1,000"; a unit or prefix after it
# ("2.2 GPa") is refused (re-asked) rather than guessed.
_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*$")
_SCI_X = re.compile(r"^\s*([-+]?\d+\.?\d*)\s*[x×*]\s*10\s*\^\s*([-+]?\d+)\s*$")


def _extract_json(text: str) -> dict[str, Any]:
    candidates = [m.group(1) for m in _FENCE.finditer(text)] + [text]
    decoder = json.JSONDecoder()
    for cand in candidates:
        for start in [i for i, ch in enumerate(cand) if ch == "{"]:
            chunk = cand[start:]
            for attempt in (chunk, re.sub(r",\s*([}\]])", r"\1", chunk)):
                try:
                    obj, _ = decoder.raw_decode(attempt)
                except json.JSONDecodeError:
                    continue
                if isinstance(obj, dict):
                    return obj
    raise ValueError("the answer holds no JSON object")


def _to_number(value: Any, key: str) -> float:
    if isinstance(value, bool):
        raise ValueError(f"{key} is not a number ({value!r})")
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        m = _SCI_X.match(value)
        if m:
            return float(m.group(1)) * 10.0 ** int(m.group(2))
        m = _NUMBER.match(value.replace(",", ""))
        if m:
            return float(m.group(1))
    raise ValueError(f"{key} is not a number ({value!r})")


def parse_answer(text: str) -> tuple[str, dict[str, float], list[str]]:
    """``(class id, {param: value incl. density}, ignored keys)`` of a raw reply.

    Raises ValueError with a one-line reason on an unusable answer.
    """
    obj = _extract_json(text)
    cls_raw = None
    values: dict[str, Any] = {}
    ignored: list[str] = []
    for key, value in obj.items():
        norm = _KEY_ALIASES.get(str(key).strip().lower().replace(" ", "_").replace("-", "_"))
        if norm == "class":
            cls_raw = value
        elif norm is not None:
            values[norm] = value
        else:
            ignored.append(str(key))
    if cls_raw is None:
        raise ValueError('the answer has no "material_type"')
    try:
        cls = normalise_class(cls_raw, field="material_type")
    except UserInputError as err:
        raise ValueError(str(err)) from None
    names = set(MATERIALS[cls].names) | {"density"}
    out: dict[str, float] = {}
    for key, value in values.items():
        if key not in names:
            if value is not None:
                ignored.append(key)
            continue
        if value is None:
            continue
        out[key] = _to_number(value, key)
    return cls, out, ignored


def _validated(
    text: str, source: str = "llm", table: str | None = None
) -> tuple[MaterialParams, list[Clamp], list[str]]:
    cls, values, ignored = parse_answer(text)
    try:
        # Physically impossible values (a negative modulus, nu > 0.5) raise here too,
        # so they are re-asked once and then refused; out-of-range ones are clamped
        # (into range table ``table``: extended, paper; None: the active one).
        params, clamps = validate(
            cls, values, on_out_of_range="clamp", origin="answer", source=source, table=table
        )
    except UserInputError as err:
        raise ValueError(str(err)) from None
    return params, clamps, ignored


# --- the client -----------------------------------------------------------------------


def _content_text(response: Any) -> str:
    try:
        content = response.choices[0].message.content
    except (AttributeError, IndexError, TypeError):
        return ""
    if isinstance(content, list):
        return "".join(p.get("text", "") if isinstance(p, dict) else str(p) for p in content)
    return content or ""


def _causes(err: BaseException):
    seen = set()
    while err is not None and id(err) not in seen:
        seen.add(id(err))
        yield err
        err = err.__cause__ or err.__context__


def connection_failure(err: BaseException) -> str:
    """What went wrong under an ``openai.APIConnectionError``, in words.

    ``refused the connection`` (nothing listens there), ``accepted the connection and
    closed it without an answer`` (a proxy or a crashed server), ``cannot be resolved``
    (DNS), else the underlying error's class name.
    """
    import socket

    names = [type(e).__name__ for e in _causes(err)]
    chain = list(_causes(err))
    if any(isinstance(e, ConnectionRefusedError) for e in chain):
        return "refused the connection (is the server running? check --base-url)"
    if any(isinstance(e, socket.gaierror) for e in chain):
        return "cannot be resolved (check the host name in --base-url)"
    closed = ("RemoteProtocolError", "ReadError", "ConnectionResetError", "BrokenPipeError")
    if any(isinstance(e, (ConnectionResetError, BrokenPipeError)) for e in chain) or any(
        n in closed for n in names
    ):
        return "accepted the connection and closed it without an answer"
    if any("ConnectError" == n for n in names):
        return "could not be connected to (check --base-url)"
    return f"failed ({' <- '.join(dict.fromkeys(names))})"


def _chat(client: Any, opts: LLMOptions, messages: list[dict]) -> str:
    import openai

    where = opts.base_url or "the OpenAI API"
    try:
        response = client.chat.completions.create(
            model=opts.model, messages=messages, temperature=opts.temperature
        )
    except openai.APITimeoutError:
        raise LLMError(
            f"llm backend: {where} timed out: no answer within --timeout {opts.timeout:g} s "
            f"per request ({1 + opts.max_retries} tries)"
        ) from None
    except openai.APIConnectionError as err:
        raise LLMError(
            f"llm backend: {where} {connection_failure(err)} ({1 + opts.max_retries} tries)"
        ) from None
    except openai.AuthenticationError:
        raise LLMError(f"llm backend: {where} rejected the API key (HTTP 401)") from None
    except openai.APIStatusError as err:
        raise LLMError(
            f"llm backend: {where} answered HTTP {err.status_code} for model {opts.model!r}"
        ) from None
    return _content_text(response)


def make_client(opts: LLMOptions):
    """An ``openai.OpenAI`` client for resolved options (heavy import inside)."""
    import openai

    return openai.OpenAI(
        base_url=opts.base_url,
        api_key=opts.api_key,
        timeout=opts.timeout,
        max_retries=opts.max_retries,
    )


def ask_material(
    prompt: str,
    image_png: bytes | None = None,
    options: LLMOptions | None = None,
    ranged: bool = True,
    announce: bool = False,
    stream=None,
    verbose: bool = False,
    table: str | None = None,
) -> LLMAnswer:
    """Ask the LLM for the material of ``prompt`` (and reference image), validated.

    ``table``: the range table the inquiry lists and the answer is clamped into
    (``extended``, ``paper``; None: the active one).

    ``ranged=False`` is the naive (PhysFlow) inquiry without ranges. ``announce``: while
    a request is out, show on ``stream`` (stderr) that the tool is waiting, for whom and
    how long at most, so a slow server is never silent. On a terminal the line is
    erased when the answer arrives (an error then stays the only line); elsewhere it is
    written only with ``verbose`` (pipes and logs keep one line per failure).
    """
    import sys

    opts = (options or LLMOptions()).resolved()
    source = "llm" if ranged else "naive"
    client = make_client(opts)
    messages = build_messages(prompt, image_png, ranged=ranged, table=table)
    where = opts.base_url or "the OpenAI API"
    out = stream or sys.stderr

    tty = bool(getattr(out, "isatty", lambda: False)())

    def ask(what: str, msgs: list[dict]) -> str:
        line = (
            f"motionphysics: {what} {opts.model} at {where}, waiting up to "
            f"{opts.timeout:g} s per request ({opts.max_retries} retries) ..."
        )
        shown = announce and (tty or verbose)
        if shown:
            print(line, file=out, end="" if tty and not verbose else "\n", flush=True)
        try:
            return _chat(client, opts, msgs)
        finally:
            if shown and tty and not verbose:
                print("\r\033[K", file=out, end="", flush=True)

    raws: list[str] = []
    text = ask("asking", messages)
    raws.append(text)
    try:
        params, clamps, ignored = _validated(text, source, table)
    except ValueError as first:
        messages = [*messages, {"role": "assistant", "content": text}, repair_message(str(first))]
        text = ask(f"answer unusable ({first}); asking again", messages)
        raws.append(text)
        try:
            params, clamps, ignored = _validated(text, source, table)
        except ValueError as second:
            raise LLMError(
                f"llm backend: no usable answer after one re-ask ({first}; then {second})"
            ) from None
    return LLMAnswer(params, clamps, raws, ignored)


def _object_entry(obj: dict[str, Any], name: str) -> Any:
    for key, value in obj.items():
        if str(key).strip().lower() == name.lower():
            return value
    return None


def _validated_objects(text: str, names: list[str], source: str, table: str | None = None):
    """({name: (MaterialParams, clamps, ignored)} of the usable entries, {name: reason})."""
    good: dict[str, Any] = {}
    bad: dict[str, str] = {}
    try:
        obj = _extract_json(text)
    except ValueError as err:
        return good, {n: str(err) for n in names}
    for name in names:
        entry = _object_entry(obj, name)
        if entry is None:
            bad[name] = f'no answer for object "{name}"'
            continue
        if not isinstance(entry, dict):
            bad[name] = f'the answer for object "{name}" is not a JSON object'
            continue
        try:
            good[name] = _validated(json.dumps(entry), source, table)
        except ValueError as err:
            bad[name] = f'object "{name}": {err}'
    return good, bad


def ask_objects(
    prompt: str,
    names: list[str],
    image_png: bytes | None = None,
    options: LLMOptions | None = None,
    ranged: bool = True,
    announce: bool = False,
    stream=None,
    verbose: bool = False,
    table: str | None = None,
) -> dict[str, LLMAnswer]:
    """Ask once for the materials of several objects of one prompt: ``{name: LLMAnswer}``.

    The inquiry lists the object names and asks for one JSON object per name; each is
    validated and range-clamped as a one-object answer. Objects whose entry is missing
    or unusable are re-asked once (the message names them); still missing then: LLMError
    naming the objects.
    """
    import sys

    from motionphysics.init.prompt import build_objects_messages

    opts = (options or LLMOptions()).resolved()
    source = "llm" if ranged else "naive"
    client = make_client(opts)
    messages = build_objects_messages(prompt, names, image_png, ranged=ranged, table=table)
    out = stream or sys.stderr
    where = opts.base_url or "the OpenAI API"
    if announce and verbose:
        print(
            f"motionphysics: asking {opts.model} at {where} for {len(names)} objects, waiting "
            f"up to {opts.timeout:g} s per request ...",
            file=out,
            flush=True,
        )
    first = _chat(client, opts, messages)
    raws = [first]
    good, bad = _validated_objects(first, names, source, table)
    if bad:
        reasons = "; ".join(bad.values())
        messages = [
            *messages,
            {"role": "assistant", "content": first},
            repair_message(
                f"{reasons}. Give a JSON object with one entry for each of "
                + ", ".join(f'"{n}"' for n in names)
            ),
        ]
        second = _chat(client, opts, messages)
        raws.append(second)
        good2, bad2 = _validated_objects(second, list(bad), source, table)
        good.update(good2)
        if bad2:
            raise LLMError(
                "llm backend: no usable answer for "
                + ", ".join(f'object "{n}"' for n in bad2)
                + f" after one re-ask ({'; '.join(bad2.values())})"
            )
    return {n: LLMAnswer(good[n][0], good[n][1], list(raws), good[n][2]) for n in names}
