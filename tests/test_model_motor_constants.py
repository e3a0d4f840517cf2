"""k_t against k_w (issue 26, item 13): in SI a DC motor has k_t = k_w, an amplitude-invariant dq
model k_t = 1.5 k_w; a k_t typed in mNm/A as Nm/A (1000x) was accepted without a word."""
import pytest

from haa_sym.cli import main
from haa_sym.errors import ParameterError
from haa_sym.model.motor import MOTOR_CONSTANT_FACTOR, MOTOR_CONVENTIONS, motor_constants_warning
from haa_sym.model.params import actuator_path, bundled_actuators, load_params

K_T = 'k_t = { value = 0.0453,   unit = "Nm/A"'


def _file(tmp_path, k_t=None, convention=None, name="hd.toml"):
    text = actuator_path("harmonic_drive").read_text()
    assert K_T in text
    if k_t is not None:
        text = text.replace(K_T, f'k_t = {{ value = {k_t},   unit = "Nm/A"')
    if convention is not None:
        text = text.replace("[motor]\n", f'[motor]\nconvention = "{convention}"\n', 1)
    path = tmp_path / name
    path.write_text(text)
    return path


def test_every_bundled_file_and_configuration_is_consistent():
    for name, path in bundled_actuators().items():
        p = load_params(path)
        for q in [p] + [p.configuration(c) for c in p.configurations]:
            values = q.plant.as_dict()
            assert motor_constants_warning(values, p.motor_convention, p.source) is None, (name, values)
            ratio = values["k_t"] / values["k_w"] / MOTOR_CONVENTIONS[p.motor_convention]
            assert abs(ratio - 1) < 1e-9, (name, ratio)      # each states the relation its values follow
    assert load_params("qdd_leg").motor_convention == "dq_amplitude_invariant"
    assert load_params("sea").motor_convention == "dc"


def test_factor_and_conventions():
    kw = 0.05
    assert motor_constants_warning({"k_t": kw * MOTOR_CONSTANT_FACTOR * 0.99, "k_w": kw}) is None
    assert motor_constants_warning({"k_t": kw * MOTOR_CONSTANT_FACTOR * 1.01, "k_w": kw}) is not None
    assert motor_constants_warning({"k_t": kw / MOTOR_CONSTANT_FACTOR / 1.01, "k_w": kw}) is not None
    # 3.5x k_w: beyond 2x of the DC relation, within 2x of the amplitude-invariant dq one
    assert motor_constants_warning({"k_t": 3.5 * kw, "k_w": kw}, "dc") is not None
    assert motor_constants_warning({"k_t": 2.9 * kw, "k_w": kw}, "dq_amplitude_invariant") is None
    assert motor_constants_warning({"k_t": 1000 * kw, "k_w": kw}, "unchecked") is None
    assert motor_constants_warning({"k_t": 1000 * kw, "k_w": 0.0}) is None        # back-EMF left out


def test_k_t_in_mnm_per_amp_warned_once(tmp_path, capsys):
    path = _file(tmp_path, k_t=45.3)                  # 45.3 mNm/A typed as Nm/A, k_w 0.0453 V s/rad
    assert main(["margins", "--params", str(path), "--P-gain", "200", "--D-gain", "10", "-q"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if "k_t" in ln]
    assert len(lines) == 1, err
    line = lines[0]
    for piece in ("haa-sym: warning: ", "k_t = 45.3 Nm/A", "is 1000x k_w = 0.0453 V s/rad", "'dc'",
                  "k_t = 1 k_w", 'convention = "dq_amplitude_invariant"', '"unchecked"', "docs/model.md"):
        assert piece in line, (piece, line)


def test_set_k_t_warned_and_convention_silences(tmp_path, capsys):
    assert main(["margins", "--params", "sea", "--set", "k_t=45.3", "--P-gain", "200", "--D-gain", "10", "-q"]) == 0
    assert "is 1000x k_w" in capsys.readouterr().err
    # the bundled files say nothing
    assert main(["margins", "--params", "qdd_leg", "--P-gain", "200", "--D-gain", "10", "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    # a dq file stated as such: 1.5x is expected, 3x is not
    path = _file(tmp_path, k_t=0.06795, convention="dq_amplitude_invariant")
    assert main(["margins", "--params", str(path), "--P-gain", "200", "--D-gain", "10", "-q"]) == 0
    assert "warning" not in capsys.readouterr().err
    path = _file(tmp_path, k_t=45.3, convention="unchecked", name="unchecked.toml")
    assert main(["margins", "--params", str(path), "--P-gain", "200", "--D-gain", "10", "-q"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_unknown_convention_refused(tmp_path, assert_refused):
    path = _file(tmp_path, convention="ac")
    with pytest.raises(ParameterError, match=r"\[motor\]: convention = 'ac'; allowed: one of \['dc', "):
        load_params(path)
    assert_refused(["margins", "--params", str(path), "--P-gain", "200", "--D-gain", "10"], "convention = 'ac'")


def test_tune_checks_the_motor_constants_too(tmp_path, capsys):
    """tune loads its file without _params: it did not warn (the helper's noted gap)."""
    path = _file(tmp_path, k_t=45.3)
    assert main(["tune", "--params", str(path), "--out", str(tmp_path / "t.toml"),
                 "--passive-configurations", "nominal"]) == 2          # refused at once, after the check
    err = capsys.readouterr().err
    assert sum("is 1000x k_w = 0.0453 V s/rad" in ln for ln in err.splitlines()) == 1, err
