import json, sys
import numpy as np
for f in sys.argv[1:]:
    d = json.load(open(f))['cases']
    K = 5
    out = {}
    for key in ('new', 'base'):
        beh = miss = 0; g = []
        for c, r in d.items():
            m = np.median(np.array(r[key])[:, :K], 0); fl = np.median(np.array(r['flat'])[:, :K], 0)
            beh += bool(np.any(m[2:] > 1.02 * fl[2:]))
            miss += bool(np.min(fl[:5]) <= 1.05 and np.min(m[:3]) > 1.05)
            g.append(m)
        out[key] = (beh, miss, np.round(np.exp(np.mean(np.log(g), 0)), 4))
    print(f, len(d), 'new', out['new'], ' base', out['base'])
