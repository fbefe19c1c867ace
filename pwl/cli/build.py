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
    from linearize.build import SerialExecutor, build
    from linearize.spec import BuildSpec

    from .output import check_output

    check_output(args.output)
    spec = BuildSpec.load(args.spec)
    db = build(spec, args.output, executor=SerialExecutor() if args.serial else None,
               workers=args.workers, progress=not args.quiet, keep_parts=args.keep_parts)
    print(db.summary())
    return 0
