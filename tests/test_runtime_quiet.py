"""A CPU run is free of library noise; --device cuda without a driver is one clear line."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from motionphysics import runtime
from motionphysics.errors import UserInputError


def test_warp_init_prints_nothing_on_a_cpu_machine():
    code = "from motionphysics.runtime import init_warp; init_warp(); print('ok')"
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=os.environ
    )
    assert r.returncode == 0 and r.stdout.strip() == "ok"
    assert r.stderr == "", r.stderr


def test_capture_passes_other_native_output_on(capfd):
    def native():
        os.write(2, b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. x\n")
        os.write(2, b"something else\n")

    text = runtime._capture_fd2(native)
    assert "something else" in text and capfd.readouterr().err == ""


@pytest.mark.skipif(runtime.cuda_driver_present(), reason="this machine has a CUDA driver")
def test_cuda_without_driver_is_one_clear_line():
    with pytest.raises(UserInputError) as err:
        runtime.check_device("cuda")
    msg = str(err.value)
    assert msg.startswith("--device cuda: ") and "driver" in msg and "--device cpu" in msg
    assert "\n" not in msg
