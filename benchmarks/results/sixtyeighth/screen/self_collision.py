exec(open("/tmp/s67/prof_fc.py").read().split("import cProfile")[0])
import json, statistics
col = hand.collision
q0 = q.detach()
def bench(fn, n=15):
    ts=[]
    for _ in range(n):
        t=time.perf_counter(); fn(); ts.append(time.perf_counter()-t)
    return statistics.median(ts)*1e3
qq = q0.clone().requires_grad_(True)
prims = col.pose(hand.forward_kinematics(qq))
def full():
    torch.autograd.grad(torch.relu(-col.pair_signed_distances(prims)).sum(), qq, retain_graph=True)
def screened():
    torch.autograd.grad(torch.relu(-col.pair_penetrating_distances(prims)).sum(), qq, retain_graph=True)
out = {"full_ms": [], "screened_ms": []}
for r in range(5):
    out["full_ms"].append(bench(full)); out["screened_ms"].append(bench(screened))
out = {k: [round(v, 2) for v in vs] for k, vs in out.items()}
with torch.no_grad():
    d = col.pair_signed_distances(prims); npc = col.capsule_pairs.shape[0]
out["overlapping_prism_pairs"] = float((d[:, npc:] < 0).float().mean())
print(json.dumps(out))
from components.hand.geometry import capsule_prism_penetrating_distance, capsule_prism_signed_distance, capsule_capsule_signed_distance
a, b, r = prims.capsule_a.detach(), prims.capsule_b.detach(), col.capsule_radius
i, j = col.prism_pairs.unbind(-1)
args = (a[:, i], b[:, i], r[i], prims.prism_centre.detach()[:, j], prims.prism_rot.detach()[:, j], col.prism_half[j], col.prism_rounding[j])
with torch.no_grad():
    print("prism full", bench(lambda: capsule_prism_signed_distance(*args, iterations=30, eps=col.eps)))
    print("prism screened", bench(lambda: capsule_prism_penetrating_distance(*args, iterations=30, samples=5, eps=col.eps)))
    print("prism screened it1", bench(lambda: capsule_prism_penetrating_distance(*args, iterations=1, samples=5, eps=col.eps)))
    i2, j2 = col.capsule_pairs.unbind(-1)
    print("caps", bench(lambda: capsule_capsule_signed_distance(a[:, i2], b[:, i2], r[i2], a[:, j2], b[:, j2], r[j2], eps=col.eps, parallel_eps=col.parallel_eps)))
    aa, bb = args[0], args[1]
    t = torch.linspace(0,1,5)[:,None]
    from components.hand.geometry import to_local, point_prism_signed_distance
    al, bl = to_local(aa, args[3], args[4]), to_local(bb, args[3], args[4])
    along = al.unsqueeze(-2) + t*(bl-al).unsqueeze(-2)
    nearest = point_prism_signed_distance(along, args[5].unsqueeze(-2), args[6].unsqueeze(-1), eps=col.eps).amin(-1)
    bound = nearest - (bl-al).norm(dim=-1)/8 - args[2]
    print("M", int((bound<=0).sum()), "of", bound.numel())
