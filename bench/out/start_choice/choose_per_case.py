import json, sys, glob, os
import numpy as np
sys.path.insert(0, '/work/main/bench')
import convergence as cv
files = sys.argv[1:]
rows = []
for p in files:
    try: cs = json.load(open(p))['cases']
    except Exception as e: print('skip', p, e); continue
    for r in cs:
        if 'flat' not in r['methods'] or 'warm+short' not in r['methods']: continue
        s, f = r['methods']['warm+short'], r['methods']['flat']
        b = cv.behind_flat(s, f); c = cv.behind_confident(s['ratio_per_seed'], f['ratio_per_seed'], n_boot=2000)
        km, kf = cv.first_within(s['median_ratio']), cv.first_within(f['median_ratio'])
        miss = kf is not None and kf <= 4 and (km is None or km > 2)
        fmiss = kf is not None and kf in (3, 4)
        stat = r['model_error_N'] ** 2 / r['zeta_star_N2']
        rows.append(dict(case=r['case'], file=os.path.basename(p), stat=stat, behind=b['worst'] > 1.02,
                         bound=bool(c['behind'] and b['worst'] > 1.02), miss=miss, fmiss=fmiss,
                         s0=s['median_ratio'][0], s1=s['median_ratio'][1], s2=s['median_ratio'][2]))
print(len(rows), 'cases')
st = np.array([r['stat'] for r in rows])
for key in ('behind', 'bound', 'miss'):
    m = np.array([r[key] for r in rows])
    print(key, m.sum(), 'stat quantiles bad', np.round(np.quantile(st[m], [0, .25, .5, .75, 1]), 2) if m.any() else '', 'good', np.round(np.quantile(st[~m], [0, .25, .5, .75, 1]), 2))
for c in (0.5, 1, 1.5, 2, 3, 5, 10):
    fire = st > c
    beh = sum(r['behind'] and not f for r, f in zip(rows, fire))
    bnd = sum(r['bound'] and not f for r, f in zip(rows, fire))
    mis = sum((r['fmiss'] if f else r['miss']) for r, f in zip(rows, fire))
    s1bad = sum(1 for r, f in zip(rows, fire) if f and r['s1'] <= 1.05)
    print(f'c {c}: fires {fire.sum()}  behind {beh} bound {bnd} misses {mis}  (fired where shipped k1<=1.05: {s1bad})')
# oracle: per case, shipped if it passes both halves, else flat if flat passes its own 'miss' half
neither = [r for r in rows if (r['behind'] or r['miss']) and r['fmiss']]
print('oracle chooser: cases neither start passes:', len(neither))
neither_b = [r for r in rows if (r['bound'] or r['miss']) and r['fmiss']]
print('  (behind counted by bound):', len(neither_b))
