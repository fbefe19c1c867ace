"""pwl validate DB.h5: the piecewise-linear model open loop versus its nonlinear plant."""
import numpy as np

from .output import check_output, plot_or_note

#: default --max-error, % of the plant's value (every output but the stall margins): the shipped
#: demo database stays below 0.41 % in the trim tables (200 points matched on the scheduling
#: variables, standard, hot and cold day) and in 5 % fuel steps (0, 6000, 12000 m), below 0.96 %
#: at steady state at the same fuel flow on hot and cold days (the corrected-parameter model's own
#: error: docs/building.md, "Model fidelity"); a wrong matrix goes far above
MAX_ERROR = 2.0
#: default --max-sm-error, percentage points (absolute) of a stall margin: the demo database
#: stays below 0.24 points everywhere (steady state, trim tables, transients)
MAX_SM_ERROR = 0.5
#: default --transient-alts: the trim grid's lowest, middle and highest altitude (turbofan demo:
#: 0, 6000 and 12000 m)
TRANSIENT_ALTS = "grid"

HELP = ("compare the piecewise-linear model (open loop) with the nonlinear plant: steady state and "
        "trim tables on standard, hot and cold days, input steps at several altitudes; exit status "
        f"1 when any error is NaN or above --max-error (default {MAX_ERROR:g} percent of the plant's "
        f"value) or, for a stall margin, above --max-sm-error (default {MAX_SM_ERROR:g} points), or when "
        "the plant's own response to a step grows without bound (named with its unstable eigenvalue)")
# (no '%' in HELP: argparse formats the command list with it)


def add_arguments(p):
    p.add_argument("database", help="gain database (HDF5) built by pwl build")
    p.add_argument("-n", "--points", type=int, default=20,
                   help="random off-grid steady-state points per day (default %(default)s)")
    p.add_argument("--trim-points", type=int, default=200,
                   help="random off-grid points of the trim-table check at the runtime's scheduling "
                        "variables, per day (default %(default)s; 0: skip)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random points (default %(default)s)")
    p.add_argument("--days", default="std,hot,cold",
                   help="days of the steady-state and trim-table checks, of std, hot, cold (default "
                        "%(default)s; hot and cold need a plant whose environment has dTamb)")
    p.add_argument("--dT", type=float, default=15.0, metavar="K",
                   help="ambient temperature offset of the hot (+) and cold (-) days, K (default %(default)g)")
    p.add_argument("--step", type=float, default=0.05,
                   help="input step of the transients, fraction of the trim input (default %(default)g)")
    p.add_argument("--transient-alts", default=TRANSIENT_ALTS, metavar="M,M,...",
                   help="altitudes (m) of the extra transients, the other scheduling variables at the "
                        "middle of the envelope (default %(default)s: the trim grid's lowest, middle and "
                        "highest altitude; 'none': skip)")
    p.add_argument("--max-error", type=float, default=MAX_ERROR, metavar="PCT",
                   help="largest acceptable |model - plant| of any output but the stall margins, %% of "
                        "the plant's value, in every check (default %(default)g; exit status 1 above "
                        "it or on NaN)")
    p.add_argument("--max-sm-error", type=float, default=MAX_SM_ERROR, metavar="POINTS",
                   help="largest acceptable |model - plant| of a stall margin (Sm...), percentage "
                        "points (default %(default)g)")
    p.add_argument("--plot", default="",
                   help="PNG file for the transient plot, needs matplotlib (default: none)")
    p.add_argument("--plot-envelope", default="", metavar="FILE",
                   help="PNG file: |error| of every output over the envelope (trim-table points, or "
                        "steady-state points with --trim-points 0), needs matplotlib (default: none)")


def table(title, names, errs):
    """Largest |error| and RMS of every output over the rows of errs (n, k): % of value, stall
    margins in points."""
    from linearize.validate import error_unit

    print(title)
    print(f"  {'channel':<8} {'max |err|':>12} {'RMS':>8}  unit")
    for j, n in enumerate(names):
        e = errs[:, j]
        print(f"  {n:<8} {np.abs(e).max():>12.3f} {np.sqrt(np.mean(e ** 2)):>8.3f}  {error_unit(n)}")


def failures(check, names, errs, max_error, max_sm_error=MAX_SM_ERROR):
    """One line per output whose largest |error| (errs: (n, k)) is NaN or above its limit, naming
    the check, the output and by how much: ``max_error`` % of value, for stall margins
    ``max_sm_error`` percentage points."""
    from linearize.validate import error_unit, is_margin

    out = []
    for n, worst in zip(names, np.abs(errs).max(axis=0)):
        lim, unit = (max_sm_error if is_margin(n) else max_error), error_unit(n)
        if np.isnan(worst):
            out.append(f"{check}: {n} error is NaN (limit {lim:g} {unit})")
        elif worst > lim:
            out.append(f"{check}: {n} max |error| {worst:.3f} {unit} > {lim:g} {unit} "
                       f"(by {worst - lim:.3f} {unit})")
    return out


def worst(names, errs) -> str:
    """'0.426 % (Fn), 0.188 points (SmLPC)': the largest |error| of the outputs in % and of the
    stall margins in points, over every row of errs (n, k)."""
    from linearize.validate import is_margin

    if errs.size == 0:
        return "none"
    m = np.abs(errs).max(axis=0)
    parts = []
    for margin, unit in ((False, "%"), (True, "points")):
        cols = [j for j, n in enumerate(names) if is_margin(n) == margin]
        if cols:
            j = max(cols, key=lambda c: -np.inf if np.isnan(m[c]) else m[c])
            parts.append(f"{m[j]:.3f} {unit} ({names[j]})")
    return ", ".join(parts)


def parse_days(text, dT):
    """[(label, dT K)] of --days (a comma list of std, hot, cold); a ValidateError names an
    unknown day."""
    from linearize.validate import DAYS, ValidateError

    days = [d.strip() for d in text.split(",") if d.strip()]
    bad = [d for d in days if d not in DAYS]
    if bad or not days:
        raise ValidateError(f"--days {text!r}: unknown day(s) {bad}; give a comma list of {', '.join(DAYS)}")
    return [(d, DAYS[d] * dT) for d in days]


def parse_alts(text, db=None):
    """Altitudes (m) of --transient-alts ('none' or '': no extra transient; 'grid': the lowest,
    middle and highest altitude of ``db``'s trim grid, none without an altitude axis); a
    ValidateError names a value that is not a number."""
    from linearize.validate import ValidateError

    if text.strip().lower() in ("", "none"):
        return []
    if text.strip().lower() == "grid":
        axis = [a for a in (db.trim_grid.axes if db is not None else []) if a.name == "alt"]
        return [] if not axis else [axis[0].lo, 0.5 * (axis[0].lo + axis[0].hi), axis[0].hi]
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValidateError(f"--transient-alts {text!r}: expected comma-separated altitudes in m") from None


def day_label(day, dT):
    return "" if dT == 0.0 else f", {day} day (dTamb {dT:+g} K)"


def point_checks(args, db, plant, names, days):
    """Steady state and trim tables on every day: prints each table and the plant's failed trims;
    returns (failure lines, {check kind: [errs]}, envelope data [(day, points, errs)])."""
    from linearize.validate import scheduled_trims, steady_state

    bad, kinds, envelope = [], {"steady state": [], "trim tables": []}, []
    runs = [("steady state", args.points, args.seed, steady_state,
             "random off-grid points{day}, model vs plant:")]
    if args.trim_points > 0:
        runs.append(("trim tables", args.trim_points, args.seed + 1, scheduled_trims,
                     "random off-grid points{day}, matched on the runtime's scheduling variables, model vs plant:"))
    for kind, n, seed, fn, what in runs:
        envelope = []   # the last kind's points: the trim tables (more points), else steady state
        for day, dT in days:
            errs, pts, failed = fn(db, plant, n, seed, dT=dT)
            check = kind + ("" if dT == 0.0 else f" ({day} day)")
            if len(pts):
                table(f"\n{kind} at {len(pts)} " + what.format(day=day_label(day, dT)), names, errs)
                bad += failures(check, names, errs, args.max_error, args.max_sm_error)
                kinds[kind].append(errs)
                envelope.append((day, pts, errs))
            else:
                bad.append(f"{check}: no point to compare at (the plant's trim failed or the model ran away "
                           f"at every one of the {n} points)")
            for p, e in failed:
                what = "skipped" if e.startswith("the model ran away") else "plant trim failed"
                print(f"  ({what} at {np.round(p, 4).tolist()}: {e})")
    return bad, kinds, envelope


def altitude_table(trs, names, alts):
    """RMS and largest |error| of every output over each altitude's transient (columns; "diverged"
    where the plant's own response did: the FAILED line says why)."""
    from linearize.validate import error_unit

    head = "".join(f" {f'{a:g} m RMS':>12} {'max':>7}" for a in alts)
    print(f"  {'channel':<8}{head}  unit")
    for j, n in enumerate(names):
        cells = "".join(f" {'diverged':>12} {'-':>7}" if tr["diverged"] else
                        f" {tr['rms'][j]:>12.3f} {tr['max'][j]:>7.3f}" for tr in trs)
        print(f"  {n:<8}{cells}  {error_unit(n)}")


def lead_note(names, tr, args, where="") -> str:
    """A note naming the outputs of transient ``tr`` that exceed their limit only at the step's
    sample (within it at every other one), ``where`` ("at 0 m, ") first: the runtime's one-sample
    lead (docs/building.md, "Validation"), the whole step for a plant faster than dt; with their
    largest |error| elsewhere (% or points). '' when there are none."""
    from linearize.validate import error_unit, is_margin

    if tr["diverged"]:
        return ""
    k = int(np.argmax(tr["time"] >= tr["t_step"]))
    err = np.abs(tr["error"])
    rest = np.delete(err, k, axis=0).max(axis=0)
    lim = [args.max_sm_error if is_margin(n) else args.max_error for n in names]
    only = [j for j in range(len(names)) if err[k, j] > lim[j] >= rest[j]]
    if not only:
        return ""
    return (f"  ({where}{', '.join(names[j] for j in only)} above the limit only at the step's sample, "
            f"t = {tr['time'][k]:g} s: the model leads the plant by one sample, the whole step for a plant "
            "faster than dt (docs/building.md, Validation); elsewhere at most "
            + ", ".join(f"{rest[j]:.3f} {error_unit(names[j])}" for j in only) + ")")


def transient_failures(check, names, tr, args):
    """Failure lines of one transient: one naming the cause when the plant's own response
    diverged (no comparison), else :func:`failures` of its errors."""
    if tr["diverged"]:
        return [f"{check}: {tr['diverged']}"]
    return failures(check, names, tr["error"], args.max_error, args.max_sm_error)


def transient_checks(args, db, plant, names, alts):
    """The input step at the middle of the envelope (one table, as before) and at each of
    ``alts`` altitudes (one table of RMS and max per altitude); returns (failure lines, [errs] of
    the transients compared (not those whose plant diverged), the middle step's result for
    --plot)."""
    from linearize.validate import fuel_step, step_point, transients

    tr = fuel_step(db, plant, step_point(db), step=args.step)
    p = ", ".join(f"{a.name}={v:.4g}" for a, v in zip(db.trim_grid.axes, tr["p"]))
    title = f"\ntransient: {100 * args.step:g} % input step at {p}, model vs plant:"
    if tr["diverged"]:
        print(f"{title}\n  {tr['diverged']}")
    else:
        table(title, names, tr["error"])
    if note := lead_note(names, tr, args):
        print(note)
    bad = transient_failures("transient", names, tr, args)
    errs = [] if tr["diverged"] else [tr["error"]]
    asked = alts or args.transient_alts.strip().lower() == "grid"
    if asked and "alt" not in [a.name for a in db.trim_grid.axes]:
        print(f"\n(no transients at altitudes: the trim grid has no alt axis; axes {db.names['p']})")
    elif alts:
        trs = transients(db, plant, "alt", alts, step=args.step)
        others = ", ".join(f"{a.name}={v:.4g}" for a, v in zip(db.trim_grid.axes, trs[0]["p"]) if a.name != "alt")
        print(f"\ntransients: {100 * args.step:g} % input step at {others}, from trims at "
              f"{', '.join(f'{a:g}' for a in alts)} m, model vs plant (over {tr['time'][-1] + db.dt:g} s):")
        altitude_table(trs, names, alts)
        for a, t in zip(alts, trs):
            if note := lead_note(names, t, args, f"at {a:g} m, "):
                print(note)
            bad += transient_failures(f"transient at alt={a:g} m", names, t, args)
            errs += [] if t["diverged"] else [t["error"]]
    return bad, errs, tr


def run(args) -> int:
    from linearize.plant import ambient_offset_index
    from linearize.validate import outputs, plant_of, step_point
    from pwl.database import GainDatabase

    check_output(args.plot)
    check_output(args.plot_envelope)
    days = parse_days(args.days, args.dT)
    db = GainDatabase.open(args.database)
    alts = parse_alts(args.transient_alts, db)
    if "alt" in db.names["p"]:
        [step_point(db, "alt", a) for a in alts]   # every altitude within the grid, before any work
    plant = plant_of(db)
    names, _ = outputs(plant)
    if any(dT != 0.0 for _, dT in days) and ambient_offset_index(plant, plant.environment(step_point(db))) is None:
        print(f"(no hot or cold days: the environment of plant {plant.name} has no dTamb)")
        days = [(d, dT) for d, dT in days if dT == 0.0]
    bad, kinds, envelope = point_checks(args, db, plant, names, days)
    tbad, terrs, tr = transient_checks(args, db, plant, names, alts)
    bad += tbad
    cat = lambda lst: np.vstack(lst) if lst else np.empty((0, len(names)))  # noqa: E731
    print(f"\nworst steady-state error {worst(names, cat(kinds['steady state']))}, trim tables "
          f"{worst(names, cat(kinds['trim tables']))}, worst transient error {worst(names, cat(terrs))} "
          f"(limit {args.max_error:g} %, stall margins {args.max_sm_error:g} points)")
    for line in bad:
        print(f"FAILED {line}")
    if not bad:
        print("passed: every error within the limit")
    if args.plot:
        plot_or_note(_plot, args.plot, tr)
    if args.plot_envelope:
        plot_or_note(_plot_envelope, args.plot_envelope, envelope, names, [a.name for a in db.trim_grid.axes])
    return 1 if bad else 0


def _plot(tr, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = tr["names"]
    cols = 3
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(12, 2.6 * rows), squeeze=False)
    for j, n in enumerate(names):
        ax = axes[j // cols][j % cols]
        ax.plot(tr["time"], tr["truth"][:, j], label="nonlinear plant")
        ax.plot(tr["time"], tr["model"][:, j], "--", label="piecewise-linear, open loop")
        ax.set_title(n)
        ax.set_xlabel("time, s")
        ax.set_ylabel(f"{n}, {tr['units'][j]}")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="lower right")
    for j in range(len(names), rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _plot_envelope(envelope, names, axes_names, path):
    """One panel per output: |error| at every checked point of every day (colour; the largest
    drawn last, on top) over the last two trim-grid axes (Mach and NfR for the turbofan); the
    worst point is ringed and named in the title (its day and every scheduling variable)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from linearize.validate import error_unit

    days = np.concatenate([[d] * len(p) for d, p, _ in envelope])
    pts = np.vstack([p for _, p, _ in envelope])
    errs = np.abs(np.vstack([e for _, _, e in envelope]))
    ix, iy = (len(axes_names) - 2, len(axes_names) - 1) if len(axes_names) > 1 else (0, 0)
    cols = 3
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(13, 3.0 * rows), squeeze=False)
    for j, n in enumerate(names):
        ax = axes[j // cols][j % cols]
        order = np.argsort(np.nan_to_num(errs[:, j], nan=np.inf))
        sc = ax.scatter(pts[order, ix], pts[order, iy], c=errs[order, j], s=14, cmap="viridis")
        k = order[-1]
        ax.scatter(pts[k, ix], pts[k, iy], s=90, facecolors="none", edgecolors="red")
        at = ", ".join(f"{a}={v:.3g}" for a, v in zip(axes_names, pts[k]))
        ax.set_title(f"{n}: max {errs[k, j]:.3g} {error_unit(n)} ({days[k]} day, {at})", fontsize=8)
        ax.set_xlabel(axes_names[ix])
        ax.set_ylabel(axes_names[iy])
        fig.colorbar(sc, ax=ax).set_label(f"|error|, {error_unit(n)}", fontsize=8)
    for j in range(len(names), rows * cols):
        axes[j // cols][j % cols].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
