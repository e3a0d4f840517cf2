"""LoopOptions in three parts (issue 8): the loop's structure, the analysis conventions and the
numerics of the frequency grid, each validated on its own; flat field names stay the CLI's."""
import pytest

from haa_sym import AnalysisConventions, ClosedLoop, FrequencyGrid, LoopOptions, LoopStructure, ParameterError


def test_fields_are_routed_to_their_part():
    o = LoopOptions(delay=1, colgate="none", n_omega=200)
    assert o.structure == LoopStructure(delay=1)
    assert o.conventions == AnalysisConventions(colgate="none")
    assert o.numerics == FrequencyGrid(n_omega=200)
    assert (o.delay, o.colgate, o.n_omega) == (1, "none", 200)
    assert o == LoopOptions(LoopStructure(delay=1), AnalysisConventions(colgate="none"), FrequencyGrid(n_omega=200))
    assert hash(o) == hash(LoopOptions(**o.to_dict()))
    assert o.replace(port="dtheta_L1").structure.port == "dtheta_L1" and o.structure.port is None
    assert set(o.to_dict()) == set(LoopOptions.field_names())
    with pytest.raises(AttributeError):
        o.delay = 0


def test_file_backed_defaults_are_resolved_per_actuator(params):
    o = LoopOptions(delay=1).resolved(params.plant.topology)
    assert (o.structure.port, o.structure.torque_damping) == ("dtheta_L2", True)
    explicit = LoopOptions(port="dtheta_L1", torque_damping=False).resolved(params.plant.topology)
    assert (explicit.structure.port, explicit.structure.torque_damping) == ("dtheta_L1", False)


def test_a_loop_depends_on_its_structure_only(params):
    # the basis (the costly exact part) is shared by loops that differ in conventions or numerics
    a = ClosedLoop(params, LoopOptions(colgate="add", n_omega=50))
    b = ClosedLoop(params, LoopOptions())
    assert a._structure_key() == b._structure_key() and a.basis is b.basis
    c = ClosedLoop(params, LoopOptions(delay=1))
    assert c._structure_key() != b._structure_key()


@pytest.mark.parametrize("kwargs, message", [
    ({"delay": 2}, "delay = 2; allowed: 0 or 1 (samples)"),
    ({"pm_rule": "best"}, "pm_rule = 'best'; allowed: ['distance', 'min_abs', 'worst']"),
    ({"n_omega": 3}, "n_omega = 3; allowed: an integer >= 10"),
    ({"omega_min": 0.0}, "omega_min = 0.0; allowed: a finite number > 0 (rad/s)"),
    ({"passivity_tol": 1.0}, "unknown option(s) ['passivity_tol']; allowed: ['delay',"),
])
def test_bad_options_name_the_field(kwargs, message):
    with pytest.raises(ParameterError) as exc:
        LoopOptions(**kwargs)
    assert message in str(exc.value)


def test_cli_option_lists_every_field_when_unknown(assert_refused):
    assert_refused(["stability", "--P-gain", "10", "--D-gain", "1", "--option", "speed=9"],
                   ("unknown option 'speed'", "'passivity_tol_deg'", "'n_omega'"))
