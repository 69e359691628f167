# MODEL.md revision 2 read literally, Python's math module only: the entries
# of T that tests/core/transport.rs holds polnlos to (entries_computed_independently_in_python).
# Usage: python3 validation/model_entries.py   (from the repository's root)
import math, os, tomllib, sys
def sub(a,b): return [a[i]-b[i] for i in range(3)]
def add(a,b): return [a[i]+b[i] for i in range(3)]
def mul(a,s): return [x*s for x in a]
def dot(a,b): return sum(a[i]*b[i] for i in range(3))
def cross(a,b): return [a[1]*b[2]-a[2]*b[1], a[2]*b[0]-a[0]*b[2], a[0]*b[1]-a[1]*b[0]]
def norm(a): return math.sqrt(dot(a,a))
def unit(a): n=norm(a); return mul(a,1/n)
def fres(phi, eta):
    if phi < 1e-7:
        r=((eta-1)/(eta+1))**2; return r,r
    pt=math.asin(math.sin(phi)/eta)
    return (math.sin(phi-pt)/math.sin(phi+pt))**2, (math.tan(phi-pt)/math.tan(phi+pt))**2
def plane(d):
    n=unit(d['normal']); u=unit(d['u_axis']); u=unit(sub(u, mul(n, dot(n,u)))); v=cross(n,u)
    return d['center'], n, u, v, d['size'], d['grid']
def point(p, iu, iv):
    c,n,u,v,size,grid=p
    fu=(iu+0.5)/grid[0]-0.5; fv=(iv+0.5)/grid[1]-0.5
    return add(add(c, mul(u, fu*size[0])), mul(v, fv*size[1]))
def entry(path, block, ju, jv, ku, kv, text=None):
    sc=tomllib.loads(text) if text is not None else tomllib.load(open(path,'rb'))
    W=plane(sc['wall']); S=plane(sc['scene'])
    w=sc['wall']; alpha=w['roughness']; eta=w['ior']; ks=w.get('ks',1.0); kd=w.get('kd',0.0)
    diffuse=w.get('diffuse','fresnel'); model=sc.get('polarizer',{}).get('model','absorbing')
    blocks=[]
    for p in sc['pose']:
        angs=p.get('polarizer_deg',[])
        if not angs: blocks.append((p,None))
        for a in angs: blocks.append((p,a))
    pose,ang=blocks[block]; o=pose['camera']
    c0=W[0]; s0=S[0]; n=W[1]
    c=point(W,ju,jv); s=point(S,ku,kv)
    wi=unit(sub(s,c)); wo=unit(sub(o,c))
    if dot(n,wi)<=0 or dot(n,wo)<=0: return 0.0
    g=max(0.0, dot(S[1], unit(sub(c,s))))
    h=unit(add(wi,wo)); nh=dot(n,h)
    D=alpha**2/(math.pi*(nh*nh*(alpha**2-1)+1)**2)
    G1=lambda x: 2*x/(x+math.sqrt(alpha**2+(1-alpha**2)*x*x))
    ci=dot(n,wi); co=dot(n,wo)
    phi=0.5*math.acos(max(-1,min(1,dot(wi,wo))))
    Rs,Rp=fres(phi,eta)
    t=None
    if ang is not None:
        n_p=unit(sub(c0,o))
        e_s0=unit(cross(unit(sub(s0,c0)), unit(sub(o,c0))))
        q0=unit(cross(e_s0,n_p)); psi=math.radians(ang)
        q=add(add(mul(q0,math.cos(psi)), mul(cross(n_p,q0), math.sin(psi))), mul(n_p, dot(n_p,q0)*(1-math.cos(psi))))
        if model=='absorbing':
            a=cross(n_p,q); t=unit(cross(wo,a))
        else:
            t=unit(sub(q, mul(wo, dot(q,wo))))
    if t is None: Pspec=(Rs+Rp)/2
    else:
        x=cross(wi,wo)
        if norm(x)<1e-12: Pspec=Rs/2
        else:
            es=unit(x); ep=cross(es,wo)
            Pspec=(Rs*dot(t,es)**2+Rp*dot(t,ep)**2)/2
    if diffuse=='lambert':
        Pdiff = 1.0 if t is None else 0.5
    else:
        Rsi,Rpi=fres(math.acos(ci),eta); Tin=1-(Rsi+Rpi)/2
        Rso,Rpo=fres(math.acos(co),eta)
        if t is None: Pdiff=Tin*(1-(Rso+Rpo)/2)
        else:
            eso=unit(cross(n,wo)); epo=cross(eso,wo)
            Pdiff=Tin*((1-Rso)*dot(t,eso)**2+(1-Rpo)*dot(t,epo)**2)/2
    f=ks*D*G1(ci)*G1(co)/(4*ci*co)*Pspec + kd/math.pi*Pdiff
    a_k=S[4][0]/S[5][0]*S[4][1]/S[5][1]
    return a_k*g*ci/dot(sub(s,c),sub(s,c))*f
if __name__=='__main__':
    base=os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'config', 'scenes') + os.sep
    for name,blk,(ju,jv,ku,kv) in [(n,b,x) for n,b in [('brewster-nopol-3x3',0),('brewster-crossed-3x3',0),('brewster-rotating-3x3',1)] for x in [(16,16,1,1),(3,20,0,2),(31,0,2,1)]]:
        print(name, blk, (ju,jv,ku,kv), repr(entry(base+name+'.toml', blk, ju,jv,ku,kv)))
    # The revision-2 keys on the 3x3 bench (kd 0.1 with either diffuse term; transmitting).
    def keyed(name, kd, diffuse, model):
        text = open(base+name+'.toml').read().replace('kd = 0.0', f'kd = {kd}\ndiffuse = "{diffuse}"')
        return text + f'\n[polarizer]\nmodel = "{model}"\n'
    for kd, diffuse, model, name in [(0.1,'fresnel','absorbing','brewster-crossed-3x3'),(0.1,'lambert','absorbing','brewster-crossed-3x3'),(0.1,'fresnel','absorbing','brewster-nopol-3x3'),(0.0,'fresnel','transmitting','brewster-crossed-3x3')]:
        for x in [(16,16,1,1),(3,20,0,2),(31,0,2,1)]:
            print(name, kd, diffuse, model, x, repr(entry(None, 0, *x, text=keyed(name, kd, diffuse, model))))
