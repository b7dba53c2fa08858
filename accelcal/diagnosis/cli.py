"""CLI: ``accelcal diagnose PATH... [--baseline ID[,ID...]|none] [--json [--all-segments]]
[--report DIR]``.

``accelcal diagnose-benchmark`` is registered by :mod:`accelcal.validation.cli`."""
from __future__ import annotations

import json
import sys
import textwrap

import numpy as np

from .runfiles import read_paths


def _diagnose(args) -> int:
    from .core import diagnose, public
    from .report import _jd, clean_json, html_report, text_report
    from ..cli import CliError            # the CLI's one error form: "accelcal: error: ..." and exit 1
    runs = read_paths(args.paths)
    if not runs:
        raise CliError("diagnose: no readable run files in " + ", ".join(map(str, args.paths)))
    try:
        res = diagnose(runs, args.baseline)
    except ValueError as e:
        raise CliError(f"diagnose: {e}") from None
    fixes = next_runs(runs, res)
    terminal = "\n".join([text_report(res)] + [
        textwrap.fill(f"to {f['to']}: add {f['run']} ({f['minutes']:.0f} min)" if f.get("run")
                      else f"to {f['to']}: {f['note']}", 80, subsequent_indent="  ") for f in fixes])
    if args.report:
        p = html_report(res, args.report, terminal=terminal, next_runs=fixes)
        print(f"report: {p}", file=sys.stderr)
    if args.json:
        pub = public(res)
        if not args.all_segments:
            pub.pop("where_all", None)
        pub["next_runs"] = fixes
        print(json.dumps(clean_json(pub), default=_jd, allow_nan=False))
    else:
        print(terminal)
    return 0


def next_runs(runs, res) -> list[dict]:
    """For each effect the runs cannot see and each alias the diagnosis names, the best
    single run the rigs can make to fix it, or the best two where no single run does
    (:func:`accelcal.testdesign.advise`).

    Parameters
    ----------
    runs : list of RunFile
        The runs diagnosed.
    res : dict
        :func:`accelcal.diagnosis.core.diagnose`'s result (``unobservable``, ``ranking``
        with ``aliases``, ``baseline``).

    Returns
    -------
    list of dict
        ``to`` (what it fixes), ``run`` (drop-format words) and ``runs`` (keys), ``minutes``
        [min], ``predicted`` (standard uncertainties [SI]); or ``note`` when no single run
        does.
    """
    from ..effects import coefficient_spec
    from ..testdesign import DesignError, advise
    from .core import prepare_cells
    asks = [(f"see {u['effect']}", [u["effect"]], []) for u in res.get("unobservable") or []]
    for r in res.get("ranking") or []:
        for a in r.get("aliases") or []:
            other = a if isinstance(a, str) else a.get("effect")
            if other:
                asks.append((f"separate {r['effect']} from {other}", [], [(r["effect"], other)]))
    if not asks:
        return []
    cells, _ = prepare_cells(runs)
    base = list((res.get("baseline") or {}).get("effects") or [])
    out = []
    for what, targets, pairs in asks:
        try:
            adv = advise(cells, base, targets or None, pairs, max_runs=1, top=1)
            # seeing an effect may take two runs (Kip beside an unknown Kpp: 45 + 135 deg);
            # telling an effect from a coefficient by two runs of other planes leans on
            # second-order terms, and the plain answer is the gravity reference below
            if not adv.proposals and targets:
                adv = advise(cells, base, targets, pairs, max_runs=2, top=1)
        except (DesignError, ValueError, np.linalg.LinAlgError) as exc:
            out.append({"to": what, "note": f"no advice: {exc}"})
            continue
        if not adv.proposals:
            other = pairs[0][1] if pairs else None
            gravity = (other is not None and coefficient_spec(other) is not None
                       and not any(r.meta.get("test") == "tumble" for r in runs))
            out.append({"to": what, "note": ("no run or pair of runs these rigs can make does it" if targets
                                             else "no single run these rigs can make does it") + (
                f"; a tumble in the gravity field measures the unit's {other} on its own" if gravity else "")})
            continue
        p = adv.proposals[0]
        out.append({"to": what, "run": " + ".join(c.label for c in p.runs),
                    "runs": [{"test": c.test, "rig_id": c.rig_id, **c.spec} for c in p.runs],
                    "minutes": round(p.minutes, 1), "predicted": p.predicted.std_uncertainty})
    return out


def register_cli(subparsers) -> None:
    """Add the ``diagnose`` subcommand to the accelcal CLI.

    ``diagnose`` reads run files or folders, runs :func:`accelcal.diagnosis.core.diagnose`
    with ``--baseline`` and prints the text report, or one JSON object with ``--json``
    (the localisation of every segment only with ``--all-segments``); ``--report DIR``
    also writes ``DIR/diagnosis.html``.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        The ``add_subparsers()`` object of the accelcal parser.
    """
    p = subparsers.add_parser("diagnose", help="diagnose the sim-to-real gap of one or more campaigns")
    p.add_argument("paths", nargs="+", metavar="PATH", help="run files or folders")
    p.add_argument("--baseline", default=None,
                   help="effects the model already includes (comma-separated effects.md ids), or 'none' "
                        "for the bare model; default: the pipeline's own processing")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.add_argument("--all-segments", action="store_true", help="with --json: every localisation segment")
    p.add_argument("--report", metavar="DIR", help="write DIR/diagnosis.html (self-contained)")
    p.set_defaults(func=_diagnose)


def main(argv=None) -> int:
    """Standalone use, ``python -m accelcal.diagnosis.cli diagnose ...``: the accelcal CLI
    itself, so errors and exit codes are the same.

    Parameters
    ----------
    argv : list of str, optional
        Command line without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code of :func:`accelcal.cli.main` (0 done, 1 failed with a one-line
        reason, 2 usage error, 3 internal error, 130 interrupted).
    """
    from ..cli import main as accelcal_main
    return accelcal_main(argv)


if __name__ == "__main__":
    sys.exit(main())
