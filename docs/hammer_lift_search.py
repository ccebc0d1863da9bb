#!/usr/bin/env python3
"""The handle-pinch grid of docs/results.md ("hammer use"): does any BH8-282 grasp
lift a hammer lying flat on the table, by the physics lift test?

Writes the 4 training hammers (`cell objects generate --category hammer --seed 1
--count 4`) and 6 unseen ones (`--seed 7 --count 6`), then runs
`cell quality --object H --pose P --table-z 0 --spread S --preshape-rad A,A,B
--approach-to-contact --lift --json` on a 900-point grid per hammer: the palm from
above over the handle 35-60 mm from the head, yawed 176-184 deg (F3 on one side of
the handle, F1 and F2 on the other), pre-shape 1.27-1.33 rad, spread 0 or 0.1 rad;
prints the lift test's rules per hammer. About 15 minutes on 2 cores.

usage: python3 docs/hammer_lift_search.py [CELL]   (default target/release/cell)
"""
import itertools, json, math, os, subprocess, sys, tempfile
from collections import Counter

CELL = sys.argv[1] if len(sys.argv) > 1 else 'target/release/cell'


def palm_pose(target, yaw, dist=0.15):
    """Palm facing down (roll pi) turned by `yaw` about z, `dist` above `target`."""
    c, s = math.cos(yaw), math.sin(yaw)
    # Rz(yaw) Rx(pi): x = (c, s, 0), y = (s, -c, 0), z = (0, 0, -1); URDF rpy.
    return [target[0], target[1], target[2] + dist, math.pi, 0.0, math.atan2(s, c)]


def head_end_x(path):
    """The head's end toward the handle: largest x of the vertices far out in y."""
    vs = [tuple(map(float, l.split()[1:4])) for l in open(path) if l.startswith('v ')]
    ymax = max(v[1] for v in vs)
    return max(v[0] for v in vs if abs(v[1]) > 0.6 * ymax)


def lift(mesh, pose, spread, preshape):
    cmd = [CELL, 'quality', '--object', mesh, '--pose=' + ','.join('%.5f' % v for v in pose),
           '--table-z', '0', '--spread', '%.3f' % spread,
           '--preshape-rad', ','.join('%.4f' % v for v in preshape),
           '--approach-to-contact', '--lift', '--json']
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out)['lift']['rule'], ' '.join(cmd[:-1])


def main():
    tmp = tempfile.mkdtemp(prefix='hammer-search-')
    hammers = []
    for seed, count, name in [(1, 4, 'training'), (7, 6, 'unseen')]:
        out = os.path.join(tmp, name)
        subprocess.run([CELL, 'objects', 'generate', '--category', 'hammer', '--seed', str(seed),
                        '--count', str(count), '--out', out], check=True, capture_output=True)
        hammers += [os.path.join(out, f'hammer_{i:03}.obj') for i in range(count)]
    total, held = Counter(), []
    for mesh in hammers:
        neck = head_end_x(mesh)
        rules = Counter()
        for d, yaw_deg, p12, p3, spread in itertools.product(
                [0.035, 0.04, 0.045, 0.05, 0.055, 0.06], [176, 180, 184],
                [1.27, 1.285, 1.3, 1.315, 1.33], [1.27, 1.285, 1.3, 1.315, 1.33], [0.0, 0.1]):
            rule, cmd = lift(mesh, palm_pose([neck + d, 0.0, 0.012], math.radians(yaw_deg)),
                             spread, [p12, p12, p3])
            rules[rule] += 1
            if rule == 'held':
                held.append(cmd)
        total += rules
        print(os.path.relpath(mesh, tmp), dict(sorted(rules.items())), flush=True)
    print('all', sum(total.values()), 'lift tests:', dict(sorted(total.items())))
    for cmd in held:
        print('held:', cmd)


if __name__ == '__main__':
    main()
