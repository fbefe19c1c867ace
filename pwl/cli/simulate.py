"""pwl simulate: fly the turbofan model through a flight profile and write a flight log.

Channels: alt, Mach, T2, P2, TRA, Wf and the noisy sensors Nf, Nc, T24, Ps30, T30, T48, P50;
truth group: noise-free sensors, Fn, T40, stall margins, Wf, T2, P2, NfR demand and the ten
health parameters per sample. Units are the model's (``models.turbofan.UNITS``).
"""
import time

from ..errors import PwlError

HELP = "simulate a turbofan flight (profile, health, sensor noise) and write a flight log"


class SimulateError(PwlError, ValueError):
    """A ``pwl simulate`` input that cannot be used, or a flight the model cannot fly (named)."""


def _pairs(text, what):
    """``"a=1,b=2"`` -> {"a": 1.0, "b": 2.0}; :class:`SimulateError` naming the option ``what``."""
    out = {}
    if not text:
        return out
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise SimulateError(f"{what}: expected name=value, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = float(v)
        except ValueError:
            raise SimulateError(f"{what}: {v!r} is not a number (in {item!r})") from None
    return out


def _health(text, what):
    """Health fractions of option ``what``, checked against the model's names and range."""
    from models.turbofan import HealthError, check_health

    health = _pairs(text, what)
    try:
        check_health(health)
    except HealthError as e:
        raise SimulateError(f"{what}: {e}") from None
    return health


def add_arguments(p):
    p.add_argument("-o", "--output", default="flight.h5", help="log file, .h5 or .csv (default flight.h5)")
    p.add_argument("--flight", choices=("short", "long"), default="short",
                   help="profile preset: short (~13.5 min, cruise 9 km) or long (1 hour, cruise 10.7 km)")
    p.add_argument("--durations", default="",
                   help="phase durations in s overriding the preset, e.g. cruise=600,climb=400 "
                        "(phases: taxi_out, takeoff, climb, cruise, descent, approach, taxi_in)")
    p.add_argument("--cruise-alt", type=float, default=None, help="cruise altitude, m")
    p.add_argument("--cruise-mach", type=float, default=0.8, help="cruise Mach number (default 0.8)")
    p.add_argument("--dtamb", type=float, default=0.0, help="ISA temperature offset, K")
    p.add_argument("--health", default="",
                   help="health fractions, e.g. fan_eff=-0.02,hpt_eff=-0.01 (constant, or the start "
                        "values when --health-end is given)")
    p.add_argument("--health-end", default=None,
                   help="health at the end of the flight: linear drift from --health to these values")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise and throttle dither")
    p.add_argument("--noise-scale", type=float, default=1.0,
                   help="multiplier of the default sensor noise (0.25 %% speeds, 0.5 %% pressures, "
                        "0.75 %% temperatures, one sigma); 0 for none")
    p.add_argument("--no-dither", action="store_true", help="no throttle steps in climb and cruise")
    p.add_argument("--compact", action="store_true", help="float32 + gzip channels (shipped sample data)")


def run(args) -> int:
    import numpy as np

    from models.flight import DT, drift, flight_profile, simulate
    from models.turbofan import PlantError, Turbofan

    from .output import check_output

    check_output(args.output)

    from ..logs import Log, write_log

    start = _health(args.health, "--health")
    if args.health_end is not None:
        end = _health(args.health_end, "--health-end")
    if args.noise_scale < 0:
        raise SimulateError(f"--noise-scale {args.noise_scale:g} must be >= 0")
    try:  # the profile's own checks: phase names, durations, cruise altitude and Mach
        prof = flight_profile(args.flight, _pairs(args.durations, "--durations"), args.cruise_alt,
                              args.cruise_mach, args.dtamb, DT, args.seed, not args.no_dither)
    except ValueError as e:
        raise SimulateError(f"flight profile: {e}") from None
    health = drift(start, end, prof["time"]) if args.health_end is not None else start
    model = Turbofan()
    t0 = time.perf_counter()
    try:
        r = simulate(model, prof, health=health, seed=args.seed, noise_scale=args.noise_scale)
    except PlantError as e:
        raise SimulateError(f"the model cannot fly this flight: {e}") from None
    wall = time.perf_counter() - t0
    attrs = dict(r["attrs"])
    attrs.update({"profile": args.flight, "health_start": start,
                  "health_end": end if args.health_end is not None else start})
    log = Log(r["time"], r["channels"], r["units"], r["truth"], r["truth_units"], attrs)
    write_log(args.output, log, compact=args.compact)
    T = r["time"][-1] - r["time"][0]
    tr = r["truth"]
    nfr = 100.0 * tr["Nf"] / np.sqrt(tr["T2"] / 288.15) / model.Nf_design
    print(f"{args.output}: {r['time'].size} samples, {T:.0f} s of flight at dt = {r['dt']} s, "
          f"simulated in {wall:.2f} s ({T / wall:,.0f} x real time)")
    print(f"  altitude max {prof['alt'].max():.0f} m, Mach max {prof['Mach'].max():.2f}, "
          f"NfR {nfr.min():.1f}..{nfr.max():.1f} %, Fn max {tr['Fn'].max() / 1e3:.1f} kN, "
          f"T40 max {tr['T40'].max():.0f} K, min stall margins fan/LPC/HPC "
          f"{tr['SmFan'].min():.1f}/{tr['SmLPC'].min():.1f}/{tr['SmHPC'].min():.1f} %")
    hs = ", ".join(f"{k}={v:+.4f}" for k, v in start.items()) or "nominal"
    he = (" -> " + (", ".join(f"{k}={v:+.4f}" for k, v in end.items()) or "nominal")
          if args.health_end is not None else "")
    print(f"  health: {hs}{he}; noise scale {args.noise_scale:g}, seed {args.seed}")
    return 0
