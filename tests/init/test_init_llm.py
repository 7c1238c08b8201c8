"""The llm / naive backends against a real OpenAI-compatible HTTP server on loopback.

The server is the test's own (http.server in a thread on 127.0.0.1, port 0): it
records every request and answers from a script, so each test checks both what the
client sent and what it made of the reply. No test needs the internet.
"""

from __future__ import annotations

import base64
import json
import threading
import time
from dataclasses import replace
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from motionphysics.cli import main
from motionphysics.errors import UserInputError
from motionphysics.init import EstimateOptions, LLMError, LLMOptions, estimate
from motionphysics.init.llm import parse_answer
from motionphysics.materials.catalog import Clamp

SECRET = "sk-test-secret-never-printed"

GOOD = json.dumps(
    {"material_type": "Metal", "density": 7850, "E": 2.1e11, "nu": 0.30, "tau_Y": 2.5e8}
)


class FakeChatServer:
    """A minimal Chat Completions endpoint. ``replies``: str, (sleep_s, str), or an HTTP status."""

    def __init__(self, replies):
        self.replies = list(replies)
        self.requests: list[dict] = []
        self.headers: list[dict] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # keep pytest output clean
                pass

            def do_POST(self):
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                outer.requests.append(body)
                outer.headers.append({k.lower(): v for k, v in self.headers.items()})
                reply = outer.replies.pop(0) if outer.replies else "no more replies"
                if isinstance(reply, int):  # an HTTP error status
                    self.send_response(reply)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                if isinstance(reply, tuple):
                    time.sleep(reply[0])
                    reply = reply[1]
                payload = json.dumps(
                    {
                        "id": "chatcmpl-test",
                        "object": "chat.completion",
                        "created": 0,
                        "model": body.get("model", "m"),
                        "choices": [
                            {
                                "index": 0,
                                "finish_reason": "stop",
                                "message": {"role": "assistant", "content": reply},
                            }
                        ],
                        "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2},
                    }
                ).encode()
                try:
                    self.send_response(200)
                    self.send_header("Content-Type", "application/json")
                    self.send_header("Content-Length", str(len(payload)))
                    self.end_headers()
                    self.wfile.write(payload)
                except (BrokenPipeError, ConnectionResetError):
                    pass  # the client gave up (timeout test)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}/v1"

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.server.shutdown()
        self.server.server_close()


def _opts(server, timeout=10.0, retries=0):
    return EstimateOptions(
        llm=LLMOptions(
            base_url=server.base_url,
            model="test-model",
            api_key=SECRET,
            timeout=timeout,
            max_retries=retries,
        )
    )


def _user_text(request) -> str:
    content = request["messages"][1]["content"]
    if isinstance(content, list):
        return "".join(p.get("text", "") for p in content if p["type"] == "text")
    return content


def test_good_answer():
    with FakeChatServer([GOOD]) as srv:
        est = estimate("An axe is hitting the ground.", backend="llm", options=_opts(srv))
    assert est.cls == "metal" and est.density == 7850.0
    assert est.values == {"E": 2.1e11, "nu": 0.3, "tau_Y": 2.5e8}
    assert est.clamped == [] and est.raw_answer == GOOD and est.backend == "llm"
    assert len(srv.requests) == 1
    req = srv.requests[0]
    assert req["model"] == "test-model"
    text = _user_text(req)
    # the extended table (the default) with the metal range reaching down to lead
    assert "An axe is hitting the ground." in text and "E: 1e10 - 4e11 Pa" in text
    assert "do not change the type" in text
    # the key travels in the Authorization header and nowhere in the estimate
    assert srv.headers[0]["authorization"] == f"Bearer {SECRET}"
    assert SECRET not in est.to_json()


def test_range_table_of_the_inquiry_and_the_clamps():
    jelly = json.dumps({"material_type": "elastic", "density": 1050, "E": 5e3, "nu": 0.45})
    with FakeChatServer([jelly]) as srv:
        est = estimate("A wobbly jelly cube.", backend="llm", options=_opts(srv))
    assert est.values["E"] == 5e3 and est.clamped == [] and est.ranges == "extended"
    assert "E: 1e3 - 4e11 Pa" in _user_text(srv.requests[0])
    # init.ranges: paper asks with the paper's table and clamps as the paper did
    with FakeChatServer([jelly]) as srv:
        est = estimate(
            "A wobbly jelly cube.",
            backend="llm",
            options=replace(_opts(srv), ranges="paper"),
        )
    text = _user_text(srv.requests[0])
    assert "E: 1e7 - 4e11 Pa" in text and "E: 4.5e10 - 4e11 Pa" in text
    assert "do not change the type" not in text  # the paper's template
    assert est.values["E"] == 1e7 and est.clamped == [Clamp("E", 5e3, 1e7, "clamped", "llm")]


def test_answer_in_code_fence_with_text_around():
    reply = (
        'Here is my estimate:\n```json\n{\n  "material_type": "Newtonian fluid",\n'
        '  "density": 1000,\n  "mu": 0.001,\n  "kappa": 2.2e9,\n}\n```\n'
        "Water is a Newtonian fluid."
    )
    with FakeChatServer([reply]) as srv:
        est = estimate("A water droplet splashes.", backend="llm", options=_opts(srv))
    assert est.cls == "newtonian"
    assert est.values == {"mu": 0.001, "kappa": 2.2e9}
    assert len(srv.requests) == 1


def test_out_of_range_values_are_clamped_and_recorded():
    reply = json.dumps(
        {
            "material_type": "elastic",
            "density": 1.0,
            "E": 1e13,
            "nu": 0.3,
            "mu": None,
            "theta_fric": None,
        }
    )
    with FakeChatServer([reply]) as srv:
        est = estimate("A rubber duck bounces.", backend="llm", options=_opts(srv))
    assert est.values == {"E": 4e11, "nu": 0.3} and est.density == 10.0
    assert set(est.clamped) == {
        Clamp("E", 1e13, 4e11, "clamped", "llm"),
        Clamp("density", 1.0, 10.0, "clamped", "llm"),
    }
    assert len(srv.requests) == 1  # clamping, not re-asking
    d = est.to_dict()
    assert {
        "field": "E",
        "original": 1e13,
        "clamped": 4e11,
        "kind": "clamped",
        "source": "llm",
    } in d["clamped"]


def test_wrong_class_is_reasked_then_accepted():
    first = json.dumps({"material_type": "glass", "density": 2500, "E": 7e10, "nu": 0.22})
    second = json.dumps({"material_type": "Elastic", "density": 2500, "E": 7e10, "nu": 0.22})
    with FakeChatServer([first, second]) as srv:
        est = estimate("A glass vase tips over.", backend="llm", options=_opts(srv))
    assert est.cls == "elastic" and est.values == {"E": 7e10, "nu": 0.22}
    assert len(srv.requests) == 2
    follow_up = srv.requests[1]["messages"]
    assert follow_up[-2] == {"role": "assistant", "content": first}
    assert "unknown material class 'glass'" in follow_up[-1]["content"]
    assert first in est.raw_answer and second in est.raw_answer


def test_wrong_class_twice_is_a_clear_error():
    bad = json.dumps({"material_type": "glass", "density": 2500, "E": 7e10, "nu": 0.22})
    with FakeChatServer([bad, bad]) as srv, pytest.raises(LLMError) as err:
        estimate("A glass vase tips over.", backend="llm", options=_opts(srv))
    assert "after one re-ask" in str(err.value) and "\n" not in str(err.value)
    assert len(srv.requests) == 2


def test_invalid_json_twice_is_a_clear_error():
    with (
        FakeChatServer(["I think it is metal.", "{material: metal"]) as srv,
        pytest.raises(LLMError, match="no JSON object"),
    ):
        estimate("An axe.", backend="llm", options=_opts(srv))
    assert len(srv.requests) == 2
    assert isinstance(LLMError("x"), UserInputError)  # the CLI exits 2 on it


def test_missing_parameter_is_reasked():
    first = json.dumps({"material_type": "metal", "density": 7850, "E": 2e11})
    with FakeChatServer([first, GOOD]) as srv:
        est = estimate("An axe.", backend="llm", options=_opts(srv))
    assert est.cls == "metal" and len(srv.requests) == 2
    assert "nu: missing" in srv.requests[1]["messages"][-1]["content"]


def test_timeout_is_a_clear_error_in_bounded_time():
    with FakeChatServer([(3.0, GOOD)]) as srv:
        t0 = time.monotonic()
        with pytest.raises(LLMError, match="timed out: no answer within --timeout 0.5 s"):
            estimate("An axe.", backend="llm", options=_opts(srv, timeout=0.5, retries=0))
        elapsed = time.monotonic() - t0
    # one 0.5 s attempt; 2.5 s is far below the 3 s the server sleeps
    assert elapsed < 2.5


def test_transient_server_error_is_retried_with_backoff():
    with FakeChatServer([503, GOOD]) as srv:
        t0 = time.monotonic()
        est = estimate("An axe.", backend="llm", options=_opts(srv, retries=1))
        elapsed = time.monotonic() - t0
    assert est.cls == "metal" and len(srv.requests) == 2
    assert elapsed >= 0.25  # the client waited (exponential backoff starts at ~0.5 s)


def test_server_error_without_retries_is_a_clear_error():
    with FakeChatServer([500]) as srv, pytest.raises(LLMError, match="HTTP 500"):
        estimate("An axe.", backend="llm", options=_opts(srv, retries=0))


def test_image_is_sent_as_an_image_url_part(tmp_path):
    from PIL import Image

    png = tmp_path / "render.png"
    Image.new("RGB", (8, 6), (200, 30, 30)).save(png)
    with FakeChatServer([GOOD]) as srv:
        estimate("An axe is hitting the ground.", image=png, backend="llm", options=_opts(srv))
    content = srv.requests[0]["messages"][1]["content"]
    assert isinstance(content, list)
    parts = [p for p in content if p["type"] == "image_url"]
    assert len(parts) == 1
    url = parts[0]["image_url"]["url"]
    assert url.startswith("data:image/png;base64,")
    data = base64.b64decode(url.split(",", 1)[1])
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert "secondary visual reference" in _user_text(srv.requests[0])


def test_naive_backend_asks_without_ranges_and_clamps():
    reply = json.dumps(
        {"material_type": "metal", "density": 7850, "E": 2e12, "nu": 0.3, "tau_Y": 2.5e8}
    )
    with FakeChatServer([reply]) as srv:
        est = estimate("An axe.", backend="naive", options=_opts(srv))
    text = _user_text(srv.requests[0])
    assert "valid ranges" not in text and "4.5e10" not in text and "1e10 - 4e11" not in text
    assert est.backend == "naive" and est.clamped == [Clamp("E", 2e12, 4e11, "clamped", "naive")]


def test_connection_refused_is_a_clear_error():
    srv = FakeChatServer([])
    url = srv.base_url
    srv.server.server_close()  # nothing listens on that port any more
    opts = EstimateOptions(llm=LLMOptions(base_url=url, api_key=SECRET, timeout=2, max_retries=0))
    with pytest.raises(LLMError, match="refused the connection"):
        estimate("An axe.", backend="llm", options=opts)


def test_server_that_closes_the_connection_is_named_as_such():
    import socket

    lsock = socket.socket()
    lsock.bind(("127.0.0.1", 0))
    lsock.listen(4)
    stop = threading.Event()

    def accept_and_close():
        lsock.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = lsock.accept()
            except OSError:
                continue
            conn.recv(65536)
            conn.close()  # accepted, read the request, answered nothing

    t = threading.Thread(target=accept_and_close, daemon=True)
    t.start()
    url = f"http://127.0.0.1:{lsock.getsockname()[1]}/v1"
    opts = EstimateOptions(llm=LLMOptions(base_url=url, api_key=SECRET, timeout=2, max_retries=0))
    try:
        with pytest.raises(LLMError, match="accepted the connection and closed it") as err:
            estimate("An axe.", backend="llm", options=opts)
        assert "cannot connect" not in str(err.value) and "\n" not in str(err.value)
    finally:
        stop.set()
        t.join(2)
        lsock.close()


def test_waiting_is_announced_with_server_and_timeout():
    import io

    from motionphysics.init.llm import ask_material

    class Tty(io.StringIO):
        def isatty(self):
            return True

    for stream, verbose in ((Tty(), False), (io.StringIO(), True)):
        with FakeChatServer([GOOD]) as srv:
            opts = _opts(srv, timeout=7).llm
            ask_material("An axe.", None, opts, announce=True, stream=stream, verbose=verbose)
        text = stream.getvalue()
        assert "asking test-model at " + srv.base_url in text, text
        assert "up to 7 s per request" in text
        # On a terminal the line is erased once the answer is in.
        assert text.endswith("\r\033[K") == (not verbose)
    quiet = io.StringIO()  # a pipe without --verbose: nothing
    with FakeChatServer([GOOD]) as srv:
        ask_material("An axe.", None, _opts(srv).llm, announce=True, stream=quiet)
    assert quiet.getvalue() == ""


@pytest.mark.parametrize(
    "bad",
    [
        '{"material_type": "metal", "density": 7800, "E": -2e11, "nu": 0.3, "tau_Y": 2e8}',
        '{"material_type": "metal", "density": 7800, "E": 2e11, "nu": 0.8, "tau_Y": 2e8}',
        '{"material_type": "metal", "density": 0, "E": 2e11, "nu": 0.3, "tau_Y": 2e8}',
    ],
)
def test_physically_impossible_answers_are_reasked_then_refused(bad):
    with FakeChatServer([bad, bad]) as srv, pytest.raises(LLMError, match="re-ask") as err:
        estimate("An axe.", backend="llm", options=_opts(srv))
    assert len(srv.requests) == 2 and "physically impossible" in str(err.value)


def test_options_from_environment(monkeypatch):
    monkeypatch.setenv("MOTIONPHYSICS_LLM_BASE_URL", "http://127.0.0.1:9/v1")
    monkeypatch.setenv("MOTIONPHYSICS_LLM_MODEL", "llama3")
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("MOTIONPHYSICS_LLM_API_KEY", raising=False)
    o = LLMOptions().resolved()
    assert (o.base_url, o.model, o.api_key) == ("http://127.0.0.1:9/v1", "llama3", "not-needed")
    assert "api_key" not in repr(o)
    monkeypatch.delenv("MOTIONPHYSICS_LLM_BASE_URL")
    with pytest.raises(UserInputError, match="no API key"):
        LLMOptions().resolved()


@pytest.mark.parametrize(
    "reply, cls, values",
    [
        (
            '{"material_type": "non-newtonian", "density": "1300", "mu": 50, "kappa": 2e9, '
            '"tau_Y": 200, "eta": 0.5}',
            "non_newtonian",
            {"density": 1300.0, "mu": 50.0, "kappa": 2e9, "tau_Y": 200.0, "eta": 0.5},
        ),
        (
            '{"Material Type": "Sand", "Density": 1600, "friction_angle": 35}',
            "sand",
            {"density": 1600.0, "theta_fric": 35.0},
        ),
        (
            '{"material_type": "metal", "density": 7850, "E": "2.1 x 10^11", "nu": 0.3, '
            '"tau_Y": 2.5e8}',
            "metal",
            {"density": 7850.0, "E": 2.1e11, "nu": 0.3, "tau_Y": 2.5e8},
        ),
    ],
)
def test_parse_answer_spellings(reply, cls, values):
    got_cls, got, _ = parse_answer(reply)
    assert got_cls == cls and got == pytest.approx(values)


@pytest.mark.parametrize(
    "reply",
    ['{"material_type": "metal", "E": "2.2 GPa"}', "no json", "[1, 2]", '{"density": 1000}'],
)
def test_parse_answer_refuses(reply):
    with pytest.raises(ValueError):
        parse_answer(reply)


def test_cli_llm_json_output(capsys):
    with FakeChatServer([GOOD]) as srv:
        rc = main(
            [
                "init",
                "An axe is hitting the ground.",
                "--backend",
                "llm",
                "--json",
                "--base-url",
                srv.base_url,
                "--model",
                "m",
                "--timeout",
                "10",
            ]
        )
    out, err = capsys.readouterr()
    assert rc == 0
    d = json.loads(out)
    assert d["material"] == {
        "class": "metal",
        "density": 7850.0,
        "E": 2.1e11,
        "nu": 0.3,
        "tau_Y": 2.5e8,
    }
    assert d["backend"] == "llm" and d["clamped"] == [] and d["raw_answer"] == GOOD
    assert SECRET not in out + err


def test_cli_llm_error_exits_2(capsys):
    with FakeChatServer(["nope", "still nope"]) as srv:
        rc = main(
            ["init", "An axe.", "--backend", "llm", "--base-url", srv.base_url, "--timeout", "10"]
        )
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "no usable answer" in err
