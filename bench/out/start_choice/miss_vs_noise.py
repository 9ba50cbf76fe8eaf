"""Per case missing 1.05 by k = 2 (where the flat start reaches it by k = 4): the shipped
default's best median ratio by k = 2, its excess over 1.05 and the 1.05 band itself, both in
units of one sweep's error scatter near the optimum (sweep_error_sd_N2 of the stored runs).
usage: miss_vs_noise.py RESULT.json ..."""
import json, sys
sys.path.insert(0, 'bench')
import convergence as cv
for p in sys.argv[1:]:
    for r in json.load(open(p))['cases']:
        if 'flat' not in r['methods']:
            continue
        s, f = r['methods']['warm+short'], r['methods']['flat']
        km, kf = cv.first_within(s['median_ratio']), cv.first_within(f['median_ratio'])
        if not (kf is not None and kf <= 4 and (km is None or km > 2)):
            continue
        zs, sd = r['zeta_star_N2'], s.get('sweep_error_sd_N2', float('nan'))
        best2 = min(s['median_ratio'][:3])
        print(f"{r['case'][:60]:60s} best by k=2 {best2:.3f}  excess {(best2 - 1.05) * zs / sd:5.2f} sd"
              f"  band {0.05 * zs / sd:.2f} sd")
