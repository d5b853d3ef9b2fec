import numpy as np, sys
from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.chance import ChanceParams, chance_check, posterior
from prox_workflows.algorithms.vehicle import check_poses
from tools.bench.bounds import TRUE_CELL, pooled
from tools.bench.chance import fused, whole
b=RoverBody()
world,bounds,vp=fused("marsyard","approach",0.025,int(sys.argv[1]),0)
stats,g=whole(bounds)
post=posterior(stats,g,2.5,ChanceParams(),vp)
top=pooled(world.true_dem(TRUE_CELL,(g.xmin,g.ymin,g.xmin+g.width*g.cell,g.ymax)),g,np.max)
x,y,h=map(float,sys.argv[2:5])
c,s=np.cos(np.radians(h)),np.sin(np.radians(h))
for w,(hx,hy) in enumerate(b.wheels):
    wx,wy=x+c*hx-s*hy,y+s*hx+c*hy
    r0=int((g.ymax-wy)/g.cell); c0=int((wx-g.xmin)/g.cell)
    sl=(slice(r0-4,r0+5),slice(c0-4,c0+5))
    print("wheel",w, "true top max %.3f  est max %.3f" % (np.nanmax(top[sl]), np.nanmax(post.mean[sl])))
    print(" true-est\n", np.round((top[sl]-post.mean[sl])*100,1))
    print(" sd\n", np.round(np.sqrt(post.var[sl]+post.common[sl]**2)*100,1))
    print(" ceiling-only:", int((np.isnan(post.mean[sl])&np.isfinite(post.ceiling[sl])).sum()), "nothing:", int((np.isnan(post.mean[sl])&~np.isfinite(post.ceiling[sl])).sum()))
