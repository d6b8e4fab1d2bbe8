"""tests/conftest.py's require: a missing piece skips a test, or fails it under CI=true."""

import pytest
from conftest import in_ci, require, require_module


@pytest.mark.parametrize("value", ["true", "TRUE", "1", "yes"])
def test_under_ci_a_missing_piece_fails(monkeypatch, value):
    monkeypatch.setenv("CI", value)
    assert in_ci()
    with pytest.raises(pytest.fail.Exception, match="CI=true and Node.js is missing"):
        require(False, "Node.js")
    with pytest.raises(pytest.fail.Exception, match="no_such_module_here"):
        require_module("no_such_module_here")


@pytest.mark.parametrize("value", [None, "", "false", "0"])
def test_elsewhere_a_missing_piece_skips(monkeypatch, value):
    if value is None:
        monkeypatch.delenv("CI", raising=False)
    else:
        monkeypatch.setenv("CI", value)
    assert not in_ci()
    with pytest.raises(pytest.skip.Exception, match="Node.js is missing"):
        require(False, "Node.js")
    with pytest.raises(pytest.skip.Exception, match="the Python module no_such_module_here"):
        require_module("no_such_module_here")


def test_a_present_piece_goes_on(monkeypatch):
    monkeypatch.setenv("CI", "true")
    require(True, "anything")
    assert require_module("json").dumps([1]) == "[1]"

