"""Bus set-up: what `rig bus up` may and may not do."""

from __future__ import annotations

import pytest

from rig import bus as rigbus


def test_bus_up_refuses_to_make_a_virtual_twin_of_a_real_interface() -> None:
    with pytest.raises(RuntimeError, match="not a vcan name"):
        rigbus.vcan_up("can0")


def test_selection_honours_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HIL_BUS", "unixcan")
    monkeypatch.setenv("HIL_CHANNEL", "bench7")
    assert rigbus.select_transport() == ("unixcan", "bench7")
    assert rigbus.select_transport("unixcan", "other") == ("unixcan", "other")
    with pytest.raises(ValueError, match="unknown bus"):
        rigbus.select_transport("carrier-pigeon")
