"""What the new-user review of the actuator/controller work found, kept fixed."""
import subprocess
import sys

import numpy as np
import pytest

from haa_sym import ClosedLoop, load_params
from haa_sym.cli import main

from conftest import ROOT


@pytest.mark.parametrize("value, expected", [("false", False), ("True", True), ("none", None)])
def test_torque_damping_option_from_the_command_line(value, expected, capsys):
    from haa_sym.cli import _parse_options
    assert _parse_options([f"torque_damping={value}"]).structure.torque_damping is expected
    assert main(["stability", "--P-gain", "200", "--D-gain", "10", "--option", f"torque_damping={value}"]) == 0


@pytest.mark.parametrize("changes", [{}, {"Ts": 2e-4}, {"Ts": 1e-4}])
@pytest.mark.parametrize("cfg", ["extended", "retracted"])
def test_free_link_position_mode_is_marginal_not_stable(params, cfg, changes):
    # K_L2 = 0 and P_gain = 0: nothing holds the leg's position, a pole sits exactly at z = 1;
    # the rounding of the sampled plant put it either side of the circle before
    p = params.configuration(cfg).with_values(K_L2=0.0, **changes)
    res = ClosedLoop(p).stability([0.0, 10.0], [0.0, 0.0])
    assert list(res.stable) == [False, True] and list(res.marginal) == [True, False]


def test_coupling_order_in_the_file_does_not_flip_the_torque_sign(tmp_path, params):
    text = (ROOT / "model" / "hyq_haa.toml").read_text()
    rev = text.replace('between = ["rotor", "L1"]', 'between = ["L1", "rotor"]') \
              .replace('between = ["L1", "L2"]', 'between = ["L2", "L1"]')
    assert rev != text
    f = tmp_path / "rev.toml"
    f.write_text(rev)
    p = load_params(f)
    assert p.plant.topology == params.plant.topology
    P, D = np.meshgrid(np.logspace(0, 4.3, 12), np.linspace(0, 50, 6), indexing="ij")
    np.testing.assert_array_equal(ClosedLoop(p).stability(P, D).stable, ClosedLoop(params).stability(P, D).stable)


def test_unknown_set_key_is_named_before_its_value(capsys):
    assert main(["stability", "--P-gain", "1", "--D-gain", "1", "--set", "port=L1"]) == 2
    assert "unknown parameter key(s) ['port']" in capsys.readouterr().err


def test_a_closed_pipe_is_not_an_error():
    cmd = [sys.executable, "-c", "from haa_sym.cli import main; import sys; sys.exit(main(['passivity', "
           "'--P-gain', '0,200,20000,1,2,3', '--D-gain', '0,10,50,1,2,3']))"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.read(1)
    proc.stdout.close()                                # the reader goes away, as `| head -c1`
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) in (0, 1) and "Traceback" not in err and "error" not in err
