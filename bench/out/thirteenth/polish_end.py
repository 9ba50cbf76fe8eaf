import sys, json, tempfile, numpy as np
from pathlib import Path
from scipy.optimize import least_squares
sys.path.insert(0, 'bench')
import convergence as cv
f, target = sys.argv[1], sys.argv[2]
name, effects, targets = cv.load_tunnel_file(f)
cv.OWN_TUNNELS[name] = (effects, targets)
with tempfile.TemporaryDirectory() as t:
    p = cv.make_plants([name], Path(t))[0]
    kp = p.setup.geometry.key_points
    tv = p.setup.make_target(target).values(kp)
    zs, Us = cv.zeta_star(p, tv)
    sim = p.sim(0)
    tm = lambda U: float(np.mean((sim.true_field(U, kp) - tv) ** 2)) / zs
    print('U*', np.round(Us, 3), tm(Us))
    for m in ('warm+short', 'flat'):
        for seed in (0, 1):
            r = cv.run_method(p, tv, cv.METHODS[m], seed, 12)
            U = np.array(r['pwm'][-1])
            sol = least_squares(lambda x: sim.true_field(x, kp) - tv, U, bounds=(0, 0.65), xtol=1e-10, ftol=1e-12)
            print(m, seed, 'end', np.round(U, 3), '%.3f' % tm(U), '-> polished', np.round(sol.x, 3), '%.3f' % tm(sol.x))
    # the line from the end to U*
    for a in np.linspace(0, 1, 11):
        print('  line %.1f %.3f' % (a, tm((1 - a) * U + a * Us)))
