"""Fuel-to-air ratio of a turbocharged diesel engine with a slow, delayed exhaust sensor (seed 004).

Synthetic stand-in for the engine of the paper (2.2 l, 4 cylinders, common rail, NOx/O2 sensor
downstream of the after-treatment), sampled at 50 Hz. Everything is per cylinder and stroke
(mg/stroke) unless stated; engine speed n in rpm; lambda^-1 is the relative fuel-to-air ratio
14.5 m_f / m_a (0 = no fuel, 1 = stoichiometric).

Signals of one simulation (:func:`simulate`):

* ``lam_true``   the actual lambda^-1 = 14.5 m_f,true / m_a,cyl (fresh air entering the cylinders);
* ``lam_model``  the fast model of eq. (2), 14.5 m_f / m_a,hw, from the ECU's fuel estimate m_f
  (the operating-point input) and the hot-wire air reading m_a,hw. Its bias
  theta = lam_true - lam_model (eq. 3) comes from
  - the injected-fuel error: m_f,true = m_f (1 + e_f(n, m_f) + drift_f t), large for short
    injections (small m_f) and varying with rail pressure (speed);
  - the air-meter error: m_a,hw = m_a,comp (1 + e_a(n) + drift_a t) (1 + noise), with a
    speed-dependent pulsation error and white noise (the paper quotes 3.2 % non-systematic error;
    default 1.5 % at 50 Hz);
  - manifold filling: the hot wire measures compressor flow, which exceeds the cylinder flow while
    the boost pressure rises (m_a,comp = m_a,cyl + V_man/(R T) dp/dt per stroke): a transient
    bias that no operating-point table can hold;
  - optionally a global scale (sec. 4 of the paper exaggerates the drift with 1.05 lambda_m);
* ``lam_sensor`` the sensor of eq. (1): the true lambda^-1 delayed by tau (0.4 s) and filtered by
  (1 - a) / (1 - a z^-1), a = 0.96 at 50 Hz, plus white noise; readings below ``sat_level``
  (about 0.1: high O2 partial pressure, Fig. 12) saturate at that level; optional spurious spikes.

Air path: the intake pressure follows a first-order lag (turbo lag, time constant falling with
speed) towards a steady boost map p_ss(n, m_f); fresh air per stroke
m_a,cyl = eta_v(n) p V_cyl / (R T_int) (1 - egr(n, m_f)) with a low-load EGR map.

Operating-point trajectories (:class:`Trajectory`: t, n, mf): :func:`injection_steps` (constant
speed, fuel steps as in sec. 4) and :func:`drive_cycle` (engine speed and fuel from a vehicle speed
profile through a vehicle / gearbox / engine-torque model; :func:`nedc_profile` gives an
NEDC-like profile: four ECE-15 urban cycles and the extra-urban part, 1180 s).

Plain numpy; random numbers from seeded ``numpy.random.Generator`` objects only. This module
imports neither ``pwl`` nor ``linearize``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

AFR_STOICH = 14.5     # stoichiometric air-to-fuel ratio of diesel (eq. 2)
R_AIR = 287.0         # J/(kg K)
LHV = 42.8e6          # J/kg, lower heating value of diesel


# --------------------------------------------------------------------------------------------
# parameters


@dataclass(frozen=True)
class EngineParams:
    """Engine, air path and model-error parameters (Table 1 engine: 2179 cm3, 4 cylinders)."""

    displacement: float = 2.179e-3      # m3
    cylinders: int = 4
    idle_speed: float = 800.0           # rpm
    eta_indicated: float = 0.42         # indicated efficiency (fuel -> torque)
    friction: tuple = (15.0, 0.005)     # friction torque T_f = c0 + c1 n, N m
    mf_max: float = 60.0                # mg/stroke, full-load fuel
    smoke_limit: float = 0.85           # the ECU limits m_f so that its own lambda_m^-1 <= this
    p_amb: float = 1.0                  # bar
    boost_gain: float = 0.035           # bar per mg/stroke of fuel at full turbo speed
    boost_max: float = 1.5              # bar above ambient
    boost_speed: tuple = (1000.0, 2500.0)   # rpm: boost builds from the first to the second speed
    turbo_tau: float = 1.2              # s, turbo lag at 2000 rpm (scales with 2000/n)
    turbo_tau_range: tuple = (0.3, 2.5)  # s
    manifold_volume: float = 3.0e-3     # m3, intake manifold + intercooler + piping
    t_int: float = 300.0                # K at ambient pressure; + 25 K per bar of boost
    eta_v: float = 0.88                 # volumetric efficiency at 2500 rpm
    egr_max: float = 0.35               # EGR fraction at idle (falls with load and speed)
    # model errors (bias of lambda_m): fuel e_f = f0 + f1 exp(-mf/f2) + f3 (n - 2000)/2000,
    # air e_a = a0 + a1 sin(2 pi n / a2); drifts in fraction per hour; air noise (fraction, 1 sigma)
    fuel_error: tuple = (0.05, 0.25, 5.0, 0.10)
    air_error: tuple = (0.04, 0.06, 1400.0)
    fuel_drift: float = 0.02            # 1/h
    air_drift: float = -0.01            # 1/h
    air_noise: float = 0.015
    manifold_filling: bool = True
    model_scale: float = 1.0            # 1.05: the exaggerated drift of sec. 4

    @property
    def v_cyl(self) -> float:
        return self.displacement / self.cylinders


@dataclass(frozen=True)
class SensorParams:
    """Slow exhaust lambda^-1 sensor, eq. (1), plus saturation and spikes."""

    a: float = 0.96                     # first-order filter pole at 50 Hz
    tau: float = 0.4                    # s, pure delay
    noise: float = 0.004                # white noise, 1 sigma (lambda^-1 units)
    sat_level: float = 0.1              # readings below this saturate at it
    spike_rate: float = 0.0             # spurious spikes per second (Poisson)
    spike_amplitude: tuple = (0.15, 0.5)   # |amplitude| range, random sign
    spike_length: tuple = (1, 6)        # samples, inclusive range


@dataclass(frozen=True)
class VehicleParams:
    """A mid-size diesel car for the drive-cycle trajectories."""

    mass: float = 1500.0                # kg (test mass)
    cda: float = 0.70                   # m2, drag coefficient x frontal area
    c_roll: float = 0.012
    rho_air: float = 1.2
    wheel_radius: float = 0.31          # m
    final_drive: float = 3.7
    gears: tuple = (3.73, 2.05, 1.32, 0.97, 0.76)
    upshift: tuple = (16.0, 33.0, 52.0, 68.0)   # km/h: shift from gear i+1 to i+2 above these
    downshift_hyst: float = 6.0         # km/h below the upshift speed
    efficiency: float = 0.92
    rot_inertia: tuple = (0.04, 0.0025)  # equivalent mass factor 1 + c0 + c1 (i_g i_f)^2
    clutch_speed: float = 10.0          # km/h: below it (launch/stop) the engine idles or slips
    fuel_cut_speed: float = 1100.0      # rpm: fuel cut on overrun above this speed
    fuel_smoothing: float = 0.1         # s, first-order smoothing of the ECU fuel demand


# --------------------------------------------------------------------------------------------
# operating-point trajectories


@dataclass
class Trajectory:
    """Operating point at a fixed sample time: time t (s), engine speed n (rpm), ECU fuel mf
    (mg/stroke); for drive cycles also the vehicle speed v (km/h) and the gear (0 = clutch open)."""

    t: np.ndarray
    n: np.ndarray
    mf: np.ndarray
    v: np.ndarray | None = None
    gear: np.ndarray | None = None
    name: str = ""

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def __len__(self):
        return self.t.size

    def repeat(self, times: int) -> "Trajectory":
        """The same trajectory driven ``times`` times back to back (time continues)."""
        k = len(self)
        t = np.arange(k * times) * self.dt + self.t[0]
        rep = lambda x: None if x is None else np.tile(x, times)  # noqa: E731
        return Trajectory(t, rep(self.n), rep(self.mf), rep(self.v), rep(self.gear),
                          f"{self.name} x{times}")


def injection_steps(levels=(15.0, 30.0, 15.0, 22.0, 8.0, 30.0, 15.0), hold=20.0, n=1500.0,
                    dt=0.02, n_levels=None) -> Trajectory:
    """Fuel steps at constant engine speed (the tests of sec. 4): each level held ``hold`` s.

    ``n_levels`` (same length as ``levels``) optionally changes the speed with each step too.
    """
    levels = np.asarray(levels, dtype=np.float64)
    per = int(round(hold / dt))
    mf = np.repeat(levels, per)
    speed = np.full(mf.size, float(n)) if n_levels is None else np.repeat(np.asarray(n_levels, float), per)
    t = np.arange(mf.size) * dt
    return Trajectory(t, speed, mf, name=f"injection steps at {n:g} rpm")


# NEDC-like profile as (duration s, end speed km/h) segments from rest. ECE-15 urban cycle
# (195 s, plateaus 15, 32, 50, 35 km/h, first acceleration after 11 s of idle) and the
# extra-urban part (400 s, up to 120 km/h).
_ECE15 = [(11, 0), (4, 15), (8, 15), (5, 0), (21, 0),
          (5, 15), (2, 15), (5, 32), (24, 32), (11, 0), (21, 0),
          (5, 15), (2, 15), (9, 35), (2, 35), (8, 50), (12, 50), (8, 35), (13, 35), (2, 35),
          (10, 0), (7, 0)]
_EUDC = [(20, 0), (5, 15), (2, 15), (9, 35), (2, 35), (8, 50), (2, 50), (13, 70), (50, 70),
         (8, 50), (69, 50), (13, 70), (50, 70), (35, 100), (30, 100), (20, 120), (10, 120),
         (16, 80), (8, 50), (10, 0), (20, 0)]


def _profile(segments, dt):
    t_end = np.cumsum([d for d, _ in segments]).astype(float)
    t_bp = np.concatenate([[0.0], t_end])
    v_bp = np.concatenate([[0.0], [v for _, v in segments]]).astype(float)
    t = np.arange(int(round(t_bp[-1] / dt))) * dt
    return t, np.interp(t, t_bp, v_bp)


def nedc_profile(dt=0.02, urban_cycles=4, extra_urban=True):
    """NEDC-like vehicle speed profile (t s, v km/h): ``urban_cycles`` ECE-15 cycles, then the
    extra-urban part. Synthetic, from the published segment structure; not a certified table."""
    segs = list(_ECE15) * urban_cycles + (list(_EUDC) if extra_urban else [])
    return _profile(segs, dt)


def drive_cycle(t, v_kmh, vehicle: VehicleParams = VehicleParams(),
                engine: EngineParams = EngineParams(), name="drive cycle") -> Trajectory:
    """Engine speed and ECU fuel for a vehicle speed profile (inverse vehicle model).

    Road load m_eff dv/dt + c_r m g + rho/2 CdA v^2 at the wheel -> engine torque through the
    gear chosen by a speed schedule with hysteresis (clutch open below ``clutch_speed`` when
    stopping, slipping at launch) -> fuel per stroke from the indicated efficiency plus friction
    (fuel cut on overrun above ``fuel_cut_speed``, idle fuel otherwise), limited to full load;
    the fuel demand is smoothed by a short first-order lag.
    """
    t = np.asarray(t, dtype=np.float64)
    v = np.asarray(v_kmh, dtype=np.float64) / 3.6
    dt = float(t[1] - t[0])
    acc = np.gradient(v, dt)
    k = t.size
    gear = np.zeros(k, dtype=np.int64)
    g = 1
    up = np.asarray(vehicle.upshift)
    for i in range(k):
        vk = v[i] * 3.6
        while g < len(vehicle.gears) and vk > up[g - 1]:
            g += 1
        while g > 1 and vk < up[g - 2] - vehicle.downshift_hyst:
            g -= 1
        stopping = acc[i] <= 0 and vk < vehicle.clutch_speed
        gear[i] = 0 if (vk < 0.5 or stopping) else g
    i_tot = np.where(gear > 0, np.asarray(vehicle.gears)[np.maximum(gear, 1) - 1] * vehicle.final_drive, 0.0)
    omega_wheel = v / vehicle.wheel_radius
    n = omega_wheel * i_tot * 60.0 / (2 * np.pi)
    launch = (gear > 0) & (acc > 0)
    n = np.where(gear == 0, engine.idle_speed, n)
    n = np.where(launch, np.maximum(n, 1.25 * engine.idle_speed), np.maximum(n, engine.idle_speed))
    m_eff = vehicle.mass * (1.0 + vehicle.rot_inertia[0] + vehicle.rot_inertia[1] * i_tot ** 2)
    force = m_eff * acc + vehicle.c_roll * vehicle.mass * 9.81 * (v > 0.05) \
        + 0.5 * vehicle.rho_air * vehicle.cda * v ** 2
    t_wheel = force * vehicle.wheel_radius
    with np.errstate(divide="ignore", invalid="ignore"):
        t_eng = np.where(t_wheel >= 0, t_wheel / (i_tot * vehicle.efficiency), t_wheel * vehicle.efficiency / i_tot)
    t_eng = np.where(gear > 0, t_eng, 0.0)
    t_fric = engine.friction[0] + engine.friction[1] * n
    mf = fuel_for_torque(t_eng + t_fric, engine)
    idle_mf = fuel_for_torque(t_fric, engine)
    overrun = t_eng + t_fric < 0
    cut = overrun & (n > vehicle.fuel_cut_speed) & (gear > 0)
    mf = np.clip(np.maximum(mf, np.where(overrun, idle_mf, 0.0)), 0.0, engine.mf_max)
    if vehicle.fuel_smoothing > 0:
        mf = first_order(mf, np.exp(-dt / vehicle.fuel_smoothing))
    mf = np.where(cut, 0.0, mf)                  # the fuel cut itself is immediate
    return Trajectory(t, n, mf, v * 3.6, gear, name)


def fuel_for_torque(torque, engine: EngineParams = EngineParams()):
    """Fuel per stroke (mg) for an indicated torque (N m): T = z m_f LHV eta_i / (4 pi)."""
    return np.asarray(torque) * 4 * np.pi / (engine.cylinders * LHV * engine.eta_indicated) * 1e6


def nedc(dt=0.02, urban_cycles=4, extra_urban=True, vehicle=VehicleParams(), engine=EngineParams()):
    """Trajectory of the NEDC-like cycle (see :func:`nedc_profile`, :func:`drive_cycle`)."""
    t, v = nedc_profile(dt, urban_cycles, extra_urban)
    return drive_cycle(t, v, vehicle, engine, name="NEDC-like cycle")


# --------------------------------------------------------------------------------------------
# engine maps and errors


def boost_target(n, mf, e: EngineParams = EngineParams()):
    """Steady intake pressure (bar) at speed n and fuel mf."""
    s0, s1 = e.boost_speed
    turbo = np.clip((np.asarray(n) - s0) / (s1 - s0), 0.1, 1.0)
    return e.p_amb + np.minimum(e.boost_max, e.boost_gain * np.asarray(mf) * turbo)


def egr_fraction(n, mf, e: EngineParams = EngineParams()):
    return e.egr_max * np.clip(1.0 - np.asarray(mf) / 25.0, 0.0, 1.0) * np.clip((3000.0 - np.asarray(n)) / 1500.0, 0.0, 1.0)


def volumetric_efficiency(n, e: EngineParams = EngineParams()):
    return e.eta_v - 0.03 * ((np.asarray(n) - 2500.0) / 1500.0) ** 2


def fuel_error(n, mf, t=0.0, e: EngineParams = EngineParams()):
    """Relative error of the injected fuel versus the ECU's estimate (fraction), at time t (s)."""
    f0, f1, f2, f3 = e.fuel_error
    return f0 + f1 * np.exp(-np.asarray(mf) / f2) + f3 * (np.asarray(n) - 2000.0) / 2000.0 + e.fuel_drift * np.asarray(t) / 3600.0


def air_error(n, t=0.0, e: EngineParams = EngineParams()):
    """Relative systematic error of the hot-wire air reading (fraction), at time t (s)."""
    a0, a1, a2 = e.air_error
    return a0 + a1 * np.sin(2 * np.pi * np.asarray(n) / a2) + e.air_drift * np.asarray(t) / 3600.0


def steady_bias(n, mf, t=0.0, e: EngineParams = EngineParams()):
    """Noise-free steady-state bias theta = lam_true - lam_model at (n, mf, t) (boost settled)."""
    n = np.asarray(n, dtype=np.float64)
    mf = np.asarray(mf, dtype=np.float64)
    ma = air_charge(n, boost_target(n, mf, e), mf, e)
    lam = AFR_STOICH * mf * (1 + fuel_error(n, mf, t, e)) / ma
    lam_m = e.model_scale * AFR_STOICH * mf / (ma * (1 + air_error(n, t, e)))
    return lam - lam_m


def air_charge(n, p, mf, e: EngineParams = EngineParams()):
    """Fresh air entering one cylinder per stroke (mg) at intake pressure p (bar)."""
    t_int = e.t_int + 25.0 * (np.asarray(p) - e.p_amb)
    rho = np.asarray(p) * 1e5 / (R_AIR * t_int)
    return volumetric_efficiency(n, e) * rho * e.v_cyl * (1.0 - egr_fraction(n, mf, e)) * 1e6


def first_order(x, a, y0=None):
    """y[k] = a y[k-1] + (1 - a) x[k] (unit DC gain), y[-1] = y0 (default x[0])."""
    x = np.asarray(x, dtype=np.float64)
    a = np.broadcast_to(np.asarray(a, dtype=np.float64), x.shape)
    y = np.empty_like(x)
    prev = x[0] if y0 is None else y0
    for k in range(x.size):
        prev = a[k] * prev + (1.0 - a[k]) * x[k]
        y[k] = prev
    return y


# --------------------------------------------------------------------------------------------
# simulation


@dataclass
class Simulation:
    """One simulated log (all arrays of the trajectory's length)."""

    t: np.ndarray
    n: np.ndarray
    mf: np.ndarray               # ECU fuel estimate (the model's input and the table's axis)
    mf_true: np.ndarray
    ma_cyl: np.ndarray           # fresh air entering the cylinder, mg/stroke
    ma_hw: np.ndarray            # hot-wire reading, mg/stroke
    boost: np.ndarray            # bar
    lam_true: np.ndarray
    lam_model: np.ndarray
    lam_sensor: np.ndarray
    lam_filtered: np.ndarray     # noise-free delayed and filtered truth (eq. 1 without v)
    saturated: np.ndarray        # bool: the sensor reading is saturated
    spikes: np.ndarray           # bool: a spurious spike is on the reading
    engine: EngineParams = field(default_factory=EngineParams)
    sensor: SensorParams = field(default_factory=SensorParams)

    @property
    def theta(self) -> np.ndarray:
        """The model bias theta = lam_true - lam_model (eq. 3)."""
        return self.lam_true - self.lam_model

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    def slice(self, sl) -> "Simulation":
        arr = {k: getattr(self, k)[sl] for k in ("t", "n", "mf", "mf_true", "ma_cyl", "ma_hw", "boost",
                                                   "lam_true", "lam_model", "lam_sensor", "lam_filtered",
                                                   "saturated", "spikes")}
        return Simulation(**arr, engine=self.engine, sensor=self.sensor)


def simulate(traj: Trajectory, seed=0, engine: EngineParams = EngineParams(),
             sensor: SensorParams = SensorParams()) -> Simulation:
    """Simulate truth, fast model and slow sensor along a trajectory (seeded)."""
    rng = np.random.default_rng(seed)
    t, n, mf = traj.t, np.asarray(traj.n, float), np.asarray(traj.mf, float)
    dt = traj.dt
    e = engine
    # ECU smoke limiter on its own estimate needs the air reading: iterate the air path once per
    # step (the limiter acts on the previous step's air reading)
    p_ss = boost_target(n, mf, e)
    tau = np.clip(e.turbo_tau * 2000.0 / np.maximum(n, 1.0), *e.turbo_tau_range)
    k = t.size
    p = np.empty(k)
    dpdt = np.empty(k)
    mf_lim = mf.copy()
    pk = p_ss[0]
    air_noise = 1.0 + e.air_noise * rng.standard_normal(k)
    ea = air_error(n, t, e)
    strokes = n / 60.0 * e.cylinders / 2.0          # strokes per second
    ma_hw = np.empty(k)
    ma_cyl = np.empty(k)
    eta = volumetric_efficiency(n, e)
    egr = egr_fraction(n, mf, e)
    for i in range(k):
        target = e.p_amb + min(e.boost_max, e.boost_gain * mf_lim[i - 1 if i else 0]
                               * min(1.0, max(0.1, (n[i] - e.boost_speed[0]) / (e.boost_speed[1] - e.boost_speed[0]))))
        alpha = np.exp(-dt / tau[i])
        pnew = alpha * pk + (1 - alpha) * target
        dpdt[i] = (pnew - pk) / dt
        pk = pnew
        p[i] = pk
        t_int = e.t_int + 25.0 * (pk - e.p_amb)
        ma_cyl[i] = eta[i] * pk * 1e5 / (R_AIR * t_int) * e.v_cyl * (1.0 - egr[i]) * 1e6
        fill = 0.0
        if e.manifold_filling:
            fill = e.manifold_volume * dpdt[i] * 1e5 / (R_AIR * t_int) * 1e6 / max(strokes[i], 1.0)
        ma_hw[i] = max(ma_cyl[i] + fill, 1.0) * (1.0 + ea[i]) * air_noise[i]
        lim = e.smoke_limit * ma_hw[i] / AFR_STOICH
        if mf_lim[i] > lim:
            mf_lim[i] = lim
    mf = mf_lim
    mf_true = mf * (1.0 + fuel_error(n, mf, t, e))
    lam_true = AFR_STOICH * mf_true / ma_cyl
    lam_model = e.model_scale * AFR_STOICH * mf / ma_hw
    lam_f, lam_s, sat, spikes = sensor_response(lam_true, dt, sensor, rng)
    return Simulation(t, n, mf, mf_true, ma_cyl, ma_hw, p, lam_true, lam_model, lam_s, lam_f, sat, spikes,
                      engine, sensor)


def sensor_response(lam_true, dt, s: SensorParams = SensorParams(), rng=None):
    """Eq. (1) plus saturation and spikes: returns (noise-free filtered, reading, saturated, spikes)."""
    rng = np.random.default_rng(0) if rng is None else rng
    lam_true = np.asarray(lam_true, dtype=np.float64)
    k = lam_true.size
    d = int(round(s.tau / dt))
    delayed = np.concatenate([np.full(d, lam_true[0]), lam_true[: k - d]]) if d else lam_true.copy()
    lam_f = first_order(delayed, s.a)
    reading = lam_f + s.noise * rng.standard_normal(k)
    sat = reading < s.sat_level
    reading = np.where(sat, s.sat_level, reading)
    spikes = np.zeros(k, dtype=bool)
    if s.spike_rate > 0:
        count = rng.poisson(s.spike_rate * k * dt)
        starts = rng.integers(0, k, count)
        for i0 in starts:
            length = int(rng.integers(s.spike_length[0], s.spike_length[1] + 1))
            amp = rng.uniform(*s.spike_amplitude) * rng.choice([-1.0, 1.0])
            sl = slice(i0, min(k, i0 + length))
            reading[sl] = np.maximum(reading[sl] + amp, 0.0)
            spikes[sl] = True
    return lam_f, reading, sat, spikes


def with_params(obj, **changes):
    """dataclasses.replace for the frozen parameter sets (convenience for the CLI and tests)."""
    return replace(obj, **changes)
