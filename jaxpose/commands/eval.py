"""``jaxpose eval``: accuracy of an estimated pose against the ground truth (or any two link files)."""

from __future__ import annotations

import json
import os
import sys


def register(sub) -> None:
    p = sub.add_parser(
        "eval",
        help="score an estimated pose against the ground truth (PCP, MPJPE, PCK; symmetry-aware)",
        description="Compare the links of RESULT (a fit result or truth JSON) with those of TRUTH. "
        "Symmetric scores take the best matching of interchangeable links (e.g. spider legs).",
    )
    p.add_argument("result", help="result.json of `jaxpose fit` (or any file with a 'links' list)")
    p.add_argument("truth", help="truth.json of `jaxpose render` (or any file with a 'links' list)")
    p.add_argument("--skeleton", default=None, metavar="FILE",
                   help="skeleton for the symmetries (default: the one named in the truth file)")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(func=run)


def _find_skeleton(explicit, links, truth_path):
    """The skeleton named by ``--skeleton``, else by the truth file (path as given, beside it, or shipped)."""
    from ..errors import JaxposeError
    from ..io.skeleton_file import ROBOT_EXTENSIONS, load_skeleton, resolve_skeleton_path
    from ..io.capsules import capsules_named

    def load(path):  # a robot file with the capsules per link the truth's link names show
        robot = os.path.splitext(resolve_skeleton_path(path))[1].lower() in ROBOT_EXTENSIONS
        return load_skeleton(path, max_capsules=capsules_named(links.names) if robot else None)

    if explicit:
        return load(explicit), None
    candidates = []
    if links.skeleton_file:
        beside = os.path.join(os.path.dirname(os.path.abspath(truth_path)), links.skeleton_file)
        candidates += [links.skeleton_file, beside]
    if links.skeleton_name:
        candidates.append(links.skeleton_name)
    for c in candidates:
        try:
            return load(c), None
        except JaxposeError:
            continue
    return None, "no skeleton file found for the truth; symmetric scores equal the strict ones"


def run(args) -> int:
    from ..io.truth import TruthError, read_links
    from ..metrics import evaluate

    pred = read_links(args.result)
    truth = read_links(args.truth)
    missing = [n for n in truth.names if n not in pred.names]
    extra = [n for n in pred.names if n not in truth.names]
    if missing or extra:
        raise TruthError(
            f"{args.result}: links do not match {args.truth}"
            + (f"; missing {', '.join(missing[:5])}" if missing else "")
            + (f"; unknown {', '.join(extra[:5])}" if extra else "")
        )
    skel, warning = _find_skeleton(args.skeleton, truth, args.truth)
    if skel is not None and set(skel.link_names) != set(truth.names):
        if args.skeleton:
            raise TruthError(f"{args.skeleton}: skeleton {skel.name!r} has other links than {args.truth}")
        skel, warning = None, (f"skeleton {skel.name!r} does not match the truth's links; "
                               "symmetric scores equal the strict ones")
    names = list(skel.link_names) if skel is not None else list(truth.names)
    ti = [truth.names.index(n) for n in names]
    pi = [pred.names.index(n) for n in names]
    m = evaluate(pred.start[pi], pred.end[pi], truth.start[ti], truth.end[ti], skel, names)
    m["result"], m["truth"] = args.result, args.truth
    m["skeleton"] = skel.name if skel is not None else truth.skeleton_name
    if warning:
        print(f"jaxpose: warning: {warning}", file=sys.stderr)
    if args.json:
        print(json.dumps(m, indent=2))
        return 0
    s, b = m["strict"], m["symmetric"]
    unscored = m["num_links"] - m["pcp_links"]
    print(f"{m['skeleton'] or 'skeleton'}: {m['num_links']} links, {m['symmetries']} symmetries"
          + (f" ({unscored} of length zero, not scored by PCP)" if unscored else ""))
    print(f"  {'':38} {'strict':>8} {'symmetric':>10}")
    rows = [
        ("links correct (PCP, half true length)", "pcp", True),
        ("links correct (both ends within 10 cm)", "pcp_10cm", True),
        ("end points within 10 cm (PCK)", "pck_10cm", True),
        ("mean end point error (MPJPE, mm)", "mpjpe_mm", False),
    ]
    for label, key, pct in rows:
        fmt = (lambda v: f"{'-':>8}" if v is None else f"{100 * v:7.1f}%") if pct else (lambda v: f"{v:8.1f}")
        print(f"  {label:38} {fmt(s[key])} {fmt(b[key]):>10}")
    swapped = {t: p for t, p in m["matching"].items() if t != p}
    if swapped:
        print("  best matching swaps: " + ", ".join(f"{t}<-{p}" for t, p in swapped.items()))
    wrong = [n for n, r in m["per_link"].items() if r["correct"] is False]
    if wrong:
        print("  misplaced (strict PCP): " + ", ".join(wrong))
    return 0
