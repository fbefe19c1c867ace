"""pwl bench TARGET [--json]: speed benchmarks reported as ratios against a same-run reference."""
import importlib

from .output import print_result

HELP = ("benchmarks (interp: interpolation kernel vs RegularGridInterpolator; run: the runtime; "
        "stream: one sample per call vs batch; table: adaptive tables)")

#: target -> "module:function" returning a dict of figures
TARGETS = {
    "interp": "pwl.bench.speed:bench_interp",
    "run": "pwl.bench.speed:bench_run",
    "table": "pwl.bench.tables:bench_tables",
    "stream": "pwl.bench.speed:bench_stream",
}


def add_arguments(p):
    p.add_argument("target", choices=sorted(TARGETS),
                   help="interp: interpolation kernel vs scipy's RegularGridInterpolator; run: the runtime "
                        "on the demo flight vs a numpy reference; stream: pwl.streaming.Stream.step per sample vs a batch "
                        "run of the same samples; table: 2-D adaptive table updates vs numpy")
    p.add_argument("--json", action="store_true", help="print one JSON object (default: aligned lines)")


def run(args) -> int:
    mod, fn = TARGETS[args.target].split(":")
    try:
        func = getattr(importlib.import_module(mod), fn)
    except (ImportError, AttributeError):
        print(f"pwl bench {args.target}: not available in this version")
        return 2
    print_result(func(), args.json)
    return 0
