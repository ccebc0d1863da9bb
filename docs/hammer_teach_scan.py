#!/usr/bin/env python3
"""Teach-in grasps for the database hammers that the physics lifts (docs/results.md,
"Re-teaching the hammers"). For each database hammer (training family, seed 1:
db/hammer/models), a grid of level palms from above across the head (roll pi, pitch
0: F3 on the face side, F1 and F2 either side of the handle), each closed with
approach to contact on the model's mesh with the table at z = 0 by `cell quality
--approach-to-contact --lift --json`, which gives the static verdict (epsilon, force
closure: what `cell train` requires) and the physics lift test (the observer's).
A grasp counts as lifting when the lift succeeds at the observer's three frictions
(mu 0.5 x 1, 0.9, 1.1). Grid: yaw -pi/2 and +pi/2, the palm over the head's centre
-6..+6 mm along the handle (3 mm steps), pre-shape 1.0..1.3 rad, spread 0.2..0.5.

Prints one JSON line per hammer: how many grasps have force closure, lift, and
both, and the chosen grasp: among those with both, the one with the most lifting
neighbours (the grid's adjacent offsets and pre-shapes), then the largest
epsilon, as a `[[model.grasp]]` pose for db/hammer/grasps.toml.

usage: python3 docs/hammer_teach_scan.py [--cell CELL] [HAMMER ...]
       (default target/release/cell and the four database hammers; HAMMER as
       hammer_001.obj or, from cell eval novel's set, hammer-novel-1-3.obj)
"""
import itertools, json, math, os, subprocess, sys, tempfile
from concurrent.futures import ThreadPoolExecutor

ARGS = sys.argv[1:]
CELL = 'target/release/cell'
if ARGS[:1] == ['--cell']:
    CELL, ARGS = ARGS[1], ARGS[2:]
PI = math.pi
MU = 0.5
DX = [-0.006, -0.003, 0.0, 0.003, 0.006]
PRESHAPE = [1.0, 1.05, 1.1, 1.15, 1.2, 1.25, 1.3]
SPREAD = [0.2, 0.3, 0.4, 0.5]
YAW = [-PI / 2, PI / 2]


def quality(mesh, x, yaw, pre, spr, mu):
    cmd = [CELL, 'quality', '--object', mesh, '--pose=%.4f,0,0.20,%.6f,0,%.6f' % (x, PI, yaw),
           '--spread', str(spr), '--preshape-rad', str(pre), '--table-z', '0', '--mu', str(mu),
           '--approach-to-contact', '--lift', '--json']
    return json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)


def judge(mesh, head_x, key):
    yi, di, pi_, si = key
    args = (mesh, head_x + DX[di], YAW[yi], PRESHAPE[pi_], SPREAD[si])
    q = quality(*args, MU)
    lifts = q['lift']['grade'] == 'success'
    if lifts:  # the observer's other two frictions
        lifts = all(quality(*args, MU * f)['lift']['grade'] == 'success' for f in (0.9, 1.1))
    palm = q['approach']['object_from_palm']
    return key, {'fc': q['force_closure'], 'epsilon': q['epsilon'], 'lifts': lifts,
                 'palm': palm}


def scan(mesh, instance):
    p = instance['params']
    head_x = instance['bounding_box_m'][0][0] + p['head_section_m'] / 2.0
    keys = list(itertools.product(range(len(YAW)), range(len(DX)), range(len(PRESHAPE)),
                                  range(len(SPREAD))))
    with ThreadPoolExecutor(2) as pool:
        results = dict(pool.map(lambda k: judge(mesh, head_x, k), keys))

    def neighbours(k):
        yi, di, pi_, si = k
        for d, q in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            n = (yi, di + d, pi_ + q, si)
            if n in results and results[n]['lifts']:
                yield n

    both = [k for k, r in results.items() if r['fc'] and r['lifts']]
    out = {'hammer': os.path.basename(mesh),
           'head_section_mm': round(1000 * p['head_section_m'], 1), 'tests': len(keys),
           'force_closure': sum(r['fc'] for r in results.values()),
           'lifts': sum(r['lifts'] for r in results.values()), 'both': len(both)}
    if both:
        k = max(both, key=lambda k: (len(list(neighbours(k))), results[k]['epsilon']))
        yi, di, pi_, si = k
        r = results[k]
        out['chosen'] = {'lifting_neighbours': len(list(neighbours(k))), 'epsilon': r['epsilon'],
                         'dx_mm': 1000 * DX[di], 'yaw': YAW[yi],
                         'pose': {'xyz': [round(v, 5) for v in r['palm']['xyz']],
                                  'rpy': [round(v, 5) for v in r['palm']['rpy']]},
                         'spread_rad': SPREAD[si], 'preshape_rad': PRESHAPE[pi_]}
    return out


with tempfile.TemporaryDirectory() as tmp:
    # The database hammers by default; named hammers from either set (the held-apart
    # ones are `cell eval novel`'s, for the survey of what lifts at all).
    for family, count in (('training', 4), ('held-apart', 10)):
        if family == 'held-apart' and not ARGS:
            break
        out = os.path.join(tmp, family)
        subprocess.run([CELL, 'objects', 'generate', '--category', 'hammer', '--family', family,
                        '--seed', '1', '--count', str(count), '--out', out],
                       capture_output=True, check=True)
        for instance in json.load(open(os.path.join(out, 'params.json')))['instances']:
            if ARGS and instance['file'] not in ARGS:
                continue
            print(json.dumps(scan(os.path.join(out, instance['file']), instance)), flush=True)
