"""The actuator and its analysed controller as a MuJoCo model (issue 25, item 2; docs/robot.md,
"Export to MuJoCo").

:func:`export_mujoco` writes two texts: an MJCF of the plant and a Python module that runs the
controller the tool analysed in a MuJoCo control callback (``mujoco.set_mjcb_control``) at the
controller's Ts. The model, per the chain equations of docs/model.md:

* every body of the chain and the rotor is a hinge about the same axis, each a child of the
  world (its joint angle is the body's absolute angle, as the chain's states are), named after
  its body: ``rotor`` (the angle theta_m / N, the file's ``"rotor"``) and the file's body names;
* the motor is MuJoCo's ``dcmotor`` on the ``rotor`` joint, ``gear`` = N: its state is the coil
  current (``inductance`` L, ``resistance`` R), its torque k_t I on theta_m and its back-EMF k_w
  dtheta_m; the rotor's inertia J_m and friction B_m are the actuator's ``armature`` and
  ``damping`` (MuJoCo reflects both by gear^2, as the chain's virtual work does). MuJoCo's
  dcmotor has one constant K = sqrt(k_t k_w) for both; the callback scales the voltage by
  sqrt(k_t / k_w), which makes the current state sqrt(k_t / k_w) I and the coil equation and the
  torque exactly the chain's (a no-op when k_t = k_w);
* for a current-commanded structure (``structure.command == "current"``, e.g.
  ``impedance_current``: the electrical state imposed, :func:`haa_sym.loop.plant.current_commanded`)
  the motor is MuJoCo's ``motor`` on the ``rotor`` joint, ``gear`` = N, with the same ``armature``
  J_m and ``damping`` B_m: its control is the motor torque k_t I, I the current command after the
  drive (no coil, no back-EMF: the drive's current loop imposes I);
* each coupling is a fixed tendon with the joint coefficients (+1, -1): its length is
  theta_a - theta_b, its ``stiffness`` K and ``damping`` D give the spring-damper torque
  -T on a and +T on b. MuJoCo has no series elastic element (mujoco issue #1524); a tendon spans
  any two joints of the chain (a joint spring only the relative angle of a parent and child),
  and the damping of joints and tendons is integrated implicitly by the implicit integrators;
* a body's B and K (friction and stiffness to ground: for a leg its linearised gravity, the
  file's K) are the joint's ``damping`` and ``stiffness`` (springref 0). Gravity itself is off:
  the file's K is the gravity the tool analysed, linear.

The controller is :func:`haa_sym.loop.statespace.controller_batch`'s state space at the gain point
(the same elements and signal flow the maps analyse, and the matrices ``haa-sym simulate``'s C
driver runs): the exported module holds its matrices and steps x' = Ac x + Bc u, y = Cc x + Dc u
with u = [encoder angle, measured torque, T_ff, theta_ref]; it writes nothing of its own.

The drive (:mod:`haa_sym.model.drive`; the order of :mod:`haa_sym.analysis.simulate`: delay, then
lag, then the motor) runs in the same callback, which MuJoCo calls at every step and every
Runge-Kutta stage: each sample's command joins a delay line of held commands and takes effect
at t_k + delay_drive (any length, not whole steps only); the lag 1 / (tau_drive s + 1) is the
exact solution of its first-order equation between those switches, evaluated at each call's
time, and is the dcmotor's input voltage. Nothing is discretised but MuJoCo's own integration.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import numpy as np

from haa_sym._version import version
from haa_sym.errors import ParameterError
from haa_sym.loop.statespace import CONTROLLER_INPUTS, CONTROLLER_OUTPUTS, controller_batch

__all__ = ["INTEGRATORS", "DEFAULT_INTEGRATOR", "DEFAULT_STEPS_PER_SAMPLE", "MujocoExport", "export_mujoco",
           "mujoco_missing_message", "compile_check"]

#: MuJoCo's integrators an export may name (``<option integrator>``).
INTEGRATORS = ("RK4", "implicit", "implicitfast", "Euler")
#: The default integrator and MuJoCo steps per controller sample (timestep = Ts / steps). RK4's
#: stability bound on the real axis (|lambda h| < 2.78) sets the floor: HyQ's gearbox damping pole
#: (-2.4e5 1/s) needs h < 11.6 us, hence at least Ts / 100. MuJoCo's dcmotor integrates its coil
#: current to first order in h whatever the integrator (measured: the error of a voltage step
#: falls 4x when h does), so h is also at most the electrical time constant L / R over
#: ELECTRICAL_STEPS (docs/robot.md: the QDD leg, L / R = 0.17 ms: 1.6 % at Ts / 100, 0.7 % at Ts / 289).
DEFAULT_INTEGRATOR = "RK4"
DEFAULT_STEPS_PER_SAMPLE = 100
ELECTRICAL_STEPS = 50
#: The name of the optional dependency (pyproject's extra).
EXTRA = "haa_sym[mujoco]"


def mujoco_missing_message(what: str) -> str:
    return f"{what} needs MuJoCo, which is not installed; allowed: install the extra {EXTRA} " \
           f"(pip install '{EXTRA}')"


@dataclass(frozen=True)
class MujocoExport:
    """The MJCF text, the controller module's text and what they hold (``meta``: the gain point,
    the integrator, the controller's matrices and signal sources)."""

    xml: str
    controller: str
    meta: dict = field(repr=False)


def _f(v: float) -> str:
    return repr(float(v))


def _check(loop, P_gain, D_gain, integrator, steps_per_sample):
    params = loop.params
    for name, v in (("P_gain", P_gain), ("D_gain", D_gain)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) \
                or not math.isfinite(v) or v < 0:
            raise ParameterError(f"{name} = {v!r}; allowed: a finite number >= 0")
    if integrator not in INTEGRATORS:
        raise ParameterError(f"integrator = {integrator!r}; allowed: {list(INTEGRATORS)}")
    if isinstance(steps_per_sample, bool) or not isinstance(steps_per_sample, (int, np.integer)) \
            or not 1 <= steps_per_sample <= 10000:
        raise ParameterError(f"steps_per_sample = {steps_per_sample!r}; allowed: an integer in [1, 10000]")
    if loop.structure.command == "voltage" and params.plant.k_w <= 0:
        raise ParameterError(f"{params.source} [motor]: k_w = {params.plant.k_w!r}; allowed: k_w > 0 for the MuJoCo "
                             "export (its dcmotor has one constant sqrt(k_t k_w) for torque and back-EMF)")


def export_mujoco(loop, P_gain: float, D_gain: float, *, controller_module: str = "controller",
                  xml_name: str = "model.xml", integrator: str = DEFAULT_INTEGRATOR,
                  steps_per_sample: int | None = None) -> MujocoExport:
    """The MJCF of ``loop``'s plant and the module running its controller at one gain point.

    Parameters
    ----------
    loop : ClosedLoop
        Plant, controller and options (the analysed loop); its ``[drive]`` (lag, dead time)
        runs in the controller module, between the controller's command and the motor (the
        dcmotor's voltage, or for a current-commanded structure the current of a ``motor``).
    P_gain, D_gain : float
        Impedance gains of Eq. (8), Nm/rad and Nms/rad.
    controller_module : str
        The controller module's name (without ``.py``), named in the MJCF's comment.
    xml_name : str
        The MJCF's file name, which the module loads from its own directory.
    integrator : str
        MuJoCo's integrator (:data:`INTEGRATORS`; default :data:`DEFAULT_INTEGRATOR`).
    steps_per_sample : int, optional
        MuJoCo steps per controller sample: ``timestep`` = Ts / steps_per_sample (s). Default the
        larger of :data:`DEFAULT_STEPS_PER_SAMPLE` and ceil(ELECTRICAL_STEPS Ts R / L) (the
        coil's bound; a current command has no coil state: :data:`DEFAULT_STEPS_PER_SAMPLE`).

    Returns
    -------
    MujocoExport
    """
    params = loop.params
    command = loop.structure.command
    if steps_per_sample is None:
        v0 = params.plant.as_dict()
        # the dcmotor's first-order coil integration ties h to L / R; an imposed current has no coil
        electrical = math.ceil(ELECTRICAL_STEPS * params.controller.Ts * v0["R"] / v0["L"] - 1e-9) \
            if command == "voltage" else 0
        steps_per_sample = max(DEFAULT_STEPS_PER_SAMPLE, electrical)
    _check(loop, P_gain, D_gain, integrator, steps_per_sample)
    plant, top, Ts = params.plant, params.plant.topology, params.controller.Ts
    v = plant.as_dict()
    h = Ts / steps_per_sample
    Ac, Bc, Cc, Dc = (m[0] for m in controller_batch(loop, float(P_gain), float(D_gain)))
    # the torque the loop reads (loop.torque_output: the file's torque_damping or the option's)
    if top.sensor == "current" and command == "current":
        # k_t N I with I the current in effect at the sample instant (the held command, or the
        # drive's lag output), as haa-sym simulate reads the imposed current
        torque = {"kind": "command", "k_t_N": v["k_t"] * v["N"]}
    elif top.sensor == "current":
        # k_t N I from the dcmotor's current state (the actuator's force is computed after the
        # control callback, so at a sample instant it is the previous step's)
        torque = {"kind": "current", "k_t_N": v["k_t"] * v["N"]}
    else:
        damped = loop.torque_output == "T_sensor"
        torque = {"kind": "tendon", "name": top.sensor, "K": v[f"K_{top.sensor}"],
                  "D": v[f"D_{top.sensor}"] if damped else 0.0}
    names = ("rotor",) + tuple(b.name for b in top.bodies)
    k_t, k_w, N = v["k_t"], v["k_w"], v["N"]
    # the actuator's control per unit of the controller's command: the dcmotor's scaled voltage
    # (one constant sqrt(k_t k_w)), or the motor torque k_t I of the current command I
    command_scale = math.sqrt(k_t / k_w) if command == "voltage" else k_t
    meta = {"haa_sym": version(), "source": params.source, "P_gain": float(P_gain), "D_gain": float(D_gain),
            "Ts": Ts, "timestep": h, "controller_module": controller_module, "steps_per_sample": steps_per_sample, "integrator": integrator,
            "joints": list(names), "encoder_joint": top.encoder, "port_joint": top.port, "torque": torque,
            "command": command, "command_scale": command_scale,
            "current_scale": math.sqrt(k_w / k_t) if command == "voltage" else 1.0 / k_t, "gear": N,
            "tau_drive": params.drive.tau_drive, "delay_drive": params.drive.delay_drive,
            "controller_inputs": list(CONTROLLER_INPUTS), "controller_outputs": list(CONTROLLER_OUTPUTS),
            "Ac": Ac.tolist(), "Bc": Bc.tolist(), "Cc": Cc.tolist(), "Dc": Dc.tolist(),
            "configuration": params.configuration_name if hasattr(params, "configuration_name") else None}
    return MujocoExport(_xml(params, names, h, integrator, controller_module, command),
                        _controller_text(meta, xml_name), meta)


def _xml(params, names, h, integrator, controller_module, command) -> str:
    plant, top = params.plant, params.plant.topology
    v = plant.as_dict()
    # the rotor's own body carries a negligible inertia (MuJoCo wants a moving body to have one):
    # its inertia is the motor's armature J_m, reflected by gear^2; at least 1e-12 kg m^2, 1000x
    # MuJoCo's floor mjMINVAL = 1e-15 (a direct-drive rotor, J_m 1e-4 and N 1, was below it)
    eps = max(1e-12 * v["J_m"] * v["N"] ** 2, 1e-12)
    lines = [f"<!-- {params.source}: exported by haa-sym {version()} (export-mujoco); the controller runs in "
             f"{controller_module}.py (docs/robot.md, 'Export to MuJoCo'). Every hinge is a body's absolute "
             "angle about x (rad); rotor = theta_m / N. -->",
             f"<mujoco model={quoteattr(params.source)}>",
             "  <compiler angle=\"radian\" autolimits=\"true\"/>",
             f"  <option timestep=\"{_f(h)}\" integrator=\"{integrator}\" gravity=\"0 0 0\">",
             "    <flag contact=\"disable\" gravity=\"disable\"/>",
             "  </option>",
             "  <worldbody>"]

    def body(name, J, B, K, offset):
        geom = (f"      <geom type=\"cylinder\" size=\"0.02 0.005\" pos=\"{offset:g} 0 0\" euler=\"0 1.5707963267948966 0\" "
                "contype=\"0\" conaffinity=\"0\" mass=\"0\"/>")
        lines.extend([f"    <body name={quoteattr(name)}>",
                      f"      <inertial pos=\"0 0 0\" mass=\"1\" diaginertia=\"{_f(J)} {_f(J)} {_f(J)}\"/>",
                      f"      <joint name={quoteattr(name)} type=\"hinge\" axis=\"1 0 0\" damping=\"{_f(B)}\" "
                      f"stiffness=\"{_f(K)}\" springref=\"0\" armature=\"0\"/>",
                      geom, "    </body>"])

    body("rotor", eps, 0.0, 0.0, 0.0)
    for i, b in enumerate(top.bodies):
        body(b.name, v[f"J_{b.name}"], v[f"B_{b.name}"], v.get(f"K_{b.name}", 0.0), 0.02 * (i + 1))
    lines.append("  </worldbody>")
    lines.append("  <tendon>")
    for c in top.couplings:
        lines.extend([f"    <fixed name={quoteattr(c.name)} stiffness=\"{_f(v[f'K_{c.name}'])}\" "
                      f"damping=\"{_f(v[f'D_{c.name}'])}\" springlength=\"0\">",
                      f"      <joint joint={quoteattr(c.a)} coef=\"1\"/>",
                      f"      <joint joint={quoteattr(c.b)} coef=\"-1\"/>",
                      "    </fixed>"])
    lines.append("  </tendon>")
    rotor = f"armature=\"{_f(v['J_m'])}\" damping=\"{_f(v['B_m'])} 0 0\""
    if command == "voltage":
        motor = (f"    <dcmotor name=\"motor\" joint=\"rotor\" gear=\"{_f(v['N'])}\" resistance=\"{_f(v['R'])}\" "
                 f"motorconst=\"{_f(v['k_t'])} {_f(v['k_w'])}\" inductance=\"{_f(v['L'])} 0\" {rotor}/>")
    else:
        # the drive imposes the current: the control is the motor torque k_t I (Nm, motor side)
        motor = f"    <motor name=\"motor\" joint=\"rotor\" gear=\"{_f(v['N'])}\" {rotor}/>"
    lines.extend(["  <actuator>", motor,
                  "  </actuator>",
                  "</mujoco>", ""])
    return "\n".join(lines)


def compile_check(xml: str) -> None:
    """Compile the MJCF with MuJoCo (raises :class:`ParameterError` with MuJoCo's message, or
    naming the extra when MuJoCo is absent)."""
    try:
        import mujoco
    except ImportError:
        raise ParameterError(mujoco_missing_message("export-mujoco")) from None
    try:
        mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:                       # mujoco's compiler error
        raise ParameterError(f"the exported MJCF does not compile in MuJoCo {mujoco.__version__}: "
                             f"{' '.join(str(exc).split())}; allowed: parameters MuJoCo accepts") from None


def _controller_text(meta: dict, xml_name: str) -> str:
    mat = {k: repr(meta[k]) for k in ("Ac", "Bc", "Cc", "Dc")}
    return _CONTROLLER_TEMPLATE.format(
        version=meta["haa_sym"], source=meta["source"], module=meta["controller_module"], P=meta["P_gain"], D=meta["D_gain"], xml_name=xml_name,
        Ts=repr(meta["Ts"]), steps=meta["steps_per_sample"], encoder=repr(meta["encoder_joint"]),
        port=repr(meta["port_joint"]), torque=repr(meta["torque"]), command=repr(meta["command"]), cscale=repr(meta["command_scale"]),
        iscale=repr(meta["current_scale"]), gear=repr(meta["gear"]), tau=repr(meta["tau_drive"]),
        delay=repr(meta["delay_drive"]), **mat)


_CONTROLLER_TEMPLATE = '''"""The controller haa-sym {version} analysed for {source} at P_gain = {P!r} Nm/rad,
D_gain = {D!r} Nms/rad, running on {xml_name} in a MuJoCo control callback at Ts (docs/robot.md,
"Export to MuJoCo"). Needs numpy and mujoco only.

The controller is the sampled state space of haa_sym.loop.statespace.controller_batch (the loop
the maps analyse): inputs u = [encoder angle (rad), measured torque (Nm), T_ff (Nm), theta_ref
(rad)], outputs [u (the command after the loop's delay: COMMAND, a voltage V or a current A), T_ref
(Nm)]; per sample y = CC x + DC u, then x = AC x + BC u. The command is held until the next
sample, then passes the drive: the dead time DELAY_DRIVE (the held command switches at
t_k + DELAY_DRIVE) and the first-order lag TAU_DRIVE (its exact solution between switches, at
every call's time), and is the motor's input (times COMMAND_SCALE: the dcmotor's voltage, or the
motor torque k_t I of a current command).

    python {{this file}} --experiment disturbance-step --amplitude 1 --duration 1   # a run, summarised
    >>> import {module}; r = {module}.run(1.0, T_dist=1.0)                    # from Python
"""
import argparse
import math
import pathlib

import mujoco
import numpy as np

XML = pathlib.Path(__file__).with_name({xml_name!r})
TS = {Ts}                      # s, the controller's sampling time
STEPS_PER_SAMPLE = {steps}     # MuJoCo steps per sample (the MJCF's timestep = TS / STEPS_PER_SAMPLE)
ENCODER = {encoder}            # the joint the encoder reads (rotor: theta_m / N)
PORT = {port}                  # the joint the external torque T_dist acts on
TORQUE = {torque}              # the measured torque: a tendon's spring (and damper), or k_t N I
GEAR = {gear}                  # N
COMMAND = {command}            # what the controller commands: "voltage" (a dcmotor) or "current" (a motor)
COMMAND_SCALE = {cscale}       # the actuator's control per unit command: sqrt(k_t / k_w) (MuJoCo's
                               # dcmotor has one constant sqrt(k_t k_w)), or k_t (the motor torque k_t I)
CURRENT_SCALE = {iscale}       # to the motor's current (A): from the dcmotor's current state, sqrt(k_w / k_t),
                               # or from the motor's control, 1 / k_t
TAU_DRIVE = {tau}              # s, the drive's first-order lag (0: none)
DELAY_DRIVE = {delay}          # s, the drive's dead time on the command (0: none)
AC = np.array({Ac})
BC = np.array({Bc})
CC = np.array({Cc})
DC = np.array({Dc})
COLUMNS = ("time", "theta", "velocity", "torque", "torque_ref", "voltage", "current")


class Controller:
    """The control callback (``mujoco.set_mjcb_control(Controller(model, data))``): at every
    sample instant k TS it reads the sensors, steps the controller and sets the command; between
    them it does nothing (the command is held). ``T_dist`` (Nm on PORT), ``T_ff`` (Nm) and
    ``theta_ref`` (rad) are constant inputs from t = 0 (set them before a run); ``log`` collects
    one row per sample (COLUMNS)."""

    def __init__(self, model, data, T_dist=0.0, T_ff=0.0, theta_ref=0.0):
        self.x = np.zeros(AC.shape[0])
        self.k = -1
        # the drive: commands waiting for their switch time (t_k + DELAY_DRIVE, V); the command in
        # effect and the lag's output at the last switch s (both 0 from rest)
        self.queue, self.v_in, self.v_lag, self.s = [], 0.0, 0.0, 0.0
        self.T_dist, self.T_ff, self.theta_ref = T_dist, T_ff, theta_ref
        self.h = model.opt.timestep
        self.rk4 = model.opt.integrator == mujoco.mjtIntegrator.mjINT_RK4
        self.pending, self.calls = -1, 0
        self.q_enc = model.jnt_qposadr[model.joint(ENCODER).id]
        port = model.joint(PORT).id
        self.q_port, self.v_port = model.jnt_qposadr[port], model.jnt_dofadr[port]
        self.tendon = model.tendon(TORQUE["name"]).id if TORQUE["kind"] == "tendon" else None
        self.log = []

    def current(self, data):
        """The motor current (A): the dcmotor's state, or the current command in effect."""
        if COMMAND == "voltage":
            return float(data.act[0]) * CURRENT_SCALE
        if TAU_DRIVE or DELAY_DRIVE:
            return self.drive(data.time)             # the drive's output is the current itself (A)
        return float(data.ctrl[0]) * CURRENT_SCALE   # the held control k_t I

    def measured_torque(self, data):
        if self.tendon is None:                      # k_t N I: the current estimate
            return TORQUE["k_t_N"] * self.current(data)
        return TORQUE["K"] * float(data.ten_length[self.tendon]) + TORQUE["D"] * float(data.ten_velocity[self.tendon])

    def drive(self, t):
        """The voltage at the motor's terminals at time t (V): the held commands after the dead
        time, through the lag (exact: v = v_in + (v_lag(s) - v_in) exp(-(t - s) / TAU_DRIVE)
        between switches s)."""
        while self.queue and self.queue[0][0] <= t + 1e-6 * self.h:
            s, v = self.queue.pop(0)
            self.v_lag, self.v_in, self.s = self.lag(s), v, s
        return self.lag(t)

    def lag(self, t):
        if TAU_DRIVE == 0:
            return self.v_in
        return self.v_in + (self.v_lag - self.v_in) * math.exp(-max(t - self.s, 0.0) / TAU_DRIVE)

    def __call__(self, model, data):
        k = int(round(data.time / TS))
        if k != self.k and abs(data.time - k * TS) <= 0.25 * self.h:
            # RK4's last stage of the step ending at t_k is a call at t_k too, on the stage's
            # state x + h k3 and still under the old command: the sample is the step's start
            # (mj_step's mj_forward, the second call at t_k; the first at t = 0 and without stages)
            self.calls = self.calls + 1 if self.pending == k else 1
            self.pending = k
            if k == 0 or not self.rk4 or self.calls == 2:
                self.sample(k, data)
        if TAU_DRIVE or DELAY_DRIVE:
            data.ctrl[0] = self.drive(data.time) * COMMAND_SCALE

    def sample(self, k, data):
        self.k = k
        u = np.array([data.qpos[self.q_enc], self.measured_torque(data), self.T_ff, self.theta_ref])
        current = self.current(data)                 # before this sample's command takes effect
        y = CC @ self.x + DC @ u
        self.x = AC @ self.x + BC @ u
        if TAU_DRIVE or DELAY_DRIVE:
            self.queue.append((k * TS + DELAY_DRIVE, float(y[0])))
        else:
            data.ctrl[0] = y[0] * COMMAND_SCALE
        data.qfrc_applied[self.v_port] = self.T_dist
        self.log.append((k * TS, u[0], data.qvel[self.v_port], u[1], y[1], y[0], current))


def load():
    """(model, data) of the exported MJCF."""
    model = mujoco.MjModel.from_xml_path(str(XML))
    return model, mujoco.MjData(model)


def run(duration, T_dist=0.0, T_ff=0.0, theta_ref=0.0):
    """Simulate ``duration`` seconds from rest with constant inputs from t = 0; one row per sample
    (the columns of haa-sym simulate's CSV, COLUMNS) as a dict of arrays."""
    model, data = load()
    ctrl = Controller(model, data, T_dist, T_ff, theta_ref)
    n = int(math.ceil(duration / TS - 1e-9)) + 1
    mujoco.set_mjcb_control(ctrl)
    try:
        for _ in range((n - 1) * STEPS_PER_SAMPLE + 1):
            mujoco.mj_step(model, data)
    finally:
        mujoco.set_mjcb_control(None)
    rows = np.array(ctrl.log[:n])
    return {{c: rows[:, i] for i, c in enumerate(COLUMNS)}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default="disturbance-step",
                    choices=["disturbance-step", "torque-step", "impedance-step"])
    ap.add_argument("--amplitude", type=float, default=1.0, help="Nm (rad for impedance-step)")
    ap.add_argument("--duration", type=float, default=1.0, help="s")
    a = ap.parse_args(argv)
    kw = {{"disturbance-step": "T_dist", "torque-step": "T_ff", "impedance-step": "theta_ref"}}[a.experiment]
    r = run(a.duration, **{{kw: a.amplitude}})
    print(f"{{a.experiment}} {{a.amplitude:g}}: theta {{r['theta'][-1]:.6g}} rad, torque {{r['torque'][-1]:.6g}} Nm "
          f"at t = {{r['time'][-1]:g}} s; peak |torque| {{np.abs(r['torque']).max():.6g}} Nm")


if __name__ == "__main__":
    main()
'''
