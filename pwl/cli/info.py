"""pwl info DB.h5: a readable summary of a gain database."""
HELP = "print a summary of a gain database (format, axes, names and units, status counts)"


def add_arguments(p):
    p.add_argument("database", help="gain database (HDF5) built by pwl build")


def run(args) -> int:
    from ..database import GainDatabase

    print(GainDatabase.open(args.database).summary())
    return 0
