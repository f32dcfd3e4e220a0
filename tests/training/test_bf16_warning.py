"""bf16 autocast on a CPU that only emulates bf16 is refused politely: a one-line warning, the run goes on."""

from __future__ import annotations

import warnings

import pytest
import torch

from navformer_rl.training import build_trainer
from navformer_rl.utils import devices


@pytest.mark.parametrize("native", [False, True])
def test_the_warning_names_the_cpu_and_the_fix_only_where_bf16_is_emulated(monkeypatch, native):
    monkeypatch.setattr(devices, "cpu_has_native_bfloat16", lambda: native)
    cpu = torch.device("cpu")
    message = devices.bfloat16_autocast_warning(cpu, "bfloat16")
    if native:
        assert message is None
    else:
        capability = torch.backends.cpu.get_cpu_capability()
        assert f"torch sees {capability}" in message and "leave model.autocast_dtype unset" in message
        assert "\n" not in message
    assert devices.bfloat16_autocast_warning(cpu, None) is None  # fp32
    assert devices.bfloat16_autocast_warning(cpu, "float16") is None
    assert devices.bfloat16_autocast_warning(torch.device("cuda"), "bfloat16") is None  # GPUs have bf16


def test_the_cpu_check_answers_on_this_machine():
    assert isinstance(devices.cpu_has_native_bfloat16(), bool)


def test_building_a_bf16_run_on_an_emulating_cpu_warns_once(monkeypatch, tiny_config):
    monkeypatch.setattr(devices, "cpu_has_native_bfloat16", lambda: False)
    with pytest.warns(UserWarning, match="bf16 is emulated there") as caught:
        build_trainer(
            tiny_config("model.autocast_dtype=bfloat16", "optim.iterations=1", "device=cpu")
        ).close()
    assert sum("bf16 is emulated" in str(w.message) for w in caught) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        build_trainer(tiny_config("optim.iterations=1", "device=cpu")).close()  # fp32: no warning
