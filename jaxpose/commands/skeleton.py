"""``jaxpose skeleton``: show a skeleton's links, DOF and genome layout."""

from __future__ import annotations

from .robot_options import add_max_capsules, check_max_capsules


def register(sub) -> None:
    p = sub.add_parser("skeleton", help="describe a skeleton file (links, DOF, genome layout)")
    p.add_argument("file", help="skeleton file or shipped name (spider, humanoid, arm7, snake)")
    p.add_argument("--genome", action="store_true", help="also list every gene")
    add_max_capsules(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io.skeleton_file import load_skeleton

    check_max_capsules(args, args.file)
    skel = load_skeleton(args.file, max_capsules=args.max_capsules)
    layout = skel.layout
    print(f"{skel.name}: {skel.num_links} links, {skel.num_dof} DOF (genome size)")
    for i, n in enumerate(skel.link_names):
        p = skel.parents[i]
        genes = sum(1 for l in layout.link_of_gene if l == i)
        print(f"  {n:<20} parent {skel.link_names[p] if p >= 0 else '-':<20} {skel.joint_types[i]:<6} "
              f"length {float(skel.length[i]):.3f} m  radius {float(skel.radius[i]):.3f} m  genes {genes}")
    if args.genome:
        for k, n in enumerate(layout.names):
            print(f"  gene {k:3d}: {n}")
    return 0
