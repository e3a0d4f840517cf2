"""``haa-sym explore`` refusals before any server starts: the missing extra, a bad --params, a bad
or busy port (one line, exit status 2)."""
import socket

from haa_sym.explore import app


def test_without_the_extra_says_what_to_install(assert_refused, monkeypatch):
    monkeypatch.setattr(app, "available", lambda: False)
    assert_refused(["explore", "--no-browser"], "pip install -e '.[explore]' in a checkout")


def test_bad_params_and_ports_are_refused(assert_refused):
    assert_refused(["explore", "--no-browser", "--params", "no_such_actuator"], "--params")
    assert_refused(["explore", "--no-browser", "--port", "0"], "--port 0")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert_refused(["explore", "--no-browser", "--port", str(port)], f"--port {port}")
