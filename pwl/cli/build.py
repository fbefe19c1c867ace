"""pwl build SPEC.toml -o DB.h5: build a gain database from a plant model (linearize.build)."""

HELP = "build a gain database from a plant model and a TOML build spec"


def add_arguments(p):
    p.add_argument("spec", help="build spec (TOML); see linearize/spec.py and docs/building.md")
    p.add_argument("-o", "--output", required=True, help="database file to write (HDF5)")
    p.add_argument("-j", "--workers", type=int, default=None, help="parallel processes (default: cores)")
    p.add_argument("--serial", action="store_true", help="run every point in this process")
    p.add_argument("--keep-parts", action="store_true",
                   help="keep the per-point results folder OUTPUT.parts after a successful build")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def run(args) -> int:
    import os

    import h5py

    from linearize.build import SerialExecutor, build
    from linearize.spec import BuildSpec

    from ..errors import PwlError
    from .output import OutputPathError, check_output

    if args.workers is not None and args.workers < 1:
        raise OutputPathError(f"-j {args.workers}: the number of processes must be 1 or more")
    check_output(args.output)
    if os.path.isfile(args.output) and not h5py.is_hdf5(args.output):
        raise OutputPathError(f"{args.output}: the file exists and is not an HDF5 file (a gain database): "
                              "give another output name or delete it first")
    spec = BuildSpec.load(args.spec)
    try:
        db = build(spec, args.output, executor=SerialExecutor() if args.serial else None,
                   workers=args.workers, progress=not args.quiet, keep_parts=args.keep_parts)
    except (PwlError, KeyboardInterrupt) as e:
        parts = f"{args.output}.parts"
        kept = [f for f in os.listdir(parts) if f != "build-key"] if os.path.isdir(parts) else []
        if kept:
            note = (f"partial results of {len(kept)} task(s) kept in {parts}/: the same command resumes from them; "
                    "remove the folder to start over")
            if isinstance(e, KeyboardInterrupt):
                import sys
                print(note, file=sys.stderr)
            else:                  # one line: the error's own
                e.args = (f"{e}; {note}",) + e.args[1:]
        raise
    print(db.summary())
    return 0
