# Reference delta tracker: Mitsuba 3 (scalar_rgb, volpath, albedo 0 = pure absorption, so
# each sample is one delta-tracking walk ending at the first real collision, like ours).
import sys, time, numpy as np, mitsuba as mi, drjit as dr
mi.set_variant('scalar_rgb')
raw = open('c.nrrd','rb').read()
data = np.frombuffer(raw[raw.index(b'\n\n')+2:], dtype='<f4').reshape(64,64,64)  # z,y,x
sigma = np.clip((data - 0.05) / 0.95, 0, 1) * 20.0  # ramp TF x density scale 20
threads = int(sys.argv[1]) if len(sys.argv) > 1 else 1
dr.set_thread_count(threads)
spp = int(sys.argv[2]) if len(sys.argv) > 2 else 64
grid = mi.VolumeGrid(sigma[..., None].astype(np.float32))
scene = mi.load_dict({
  'type': 'scene',
  'integrator': {'type': 'volpath', 'max_depth': 2},
  'sensor': {'type': 'orthographic',
     'to_world': mi.ScalarTransform4f().look_at(origin=[0.5,0.5,-2], target=[0.5,0.5,0.5], up=[0,1,0])
        @ mi.ScalarTransform4f().scale([0.5,0.5,1]),
     'film': {'type': 'hdrfilm', 'width': 48, 'height': 48, 'rfilter': {'type': 'box'}},
     'sampler': {'type': 'independent', 'sample_count': spp}},
  'emitter': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 1.0}},
  'cube': {'type': 'cube', 'bsdf': {'type': 'null'},
     'to_world': mi.ScalarTransform4f().translate([0.5,0.5,0.5]) @ mi.ScalarTransform4f().scale(0.5),
     'interior': {'type': 'heterogeneous', 'albedo': 0.0, 'scale': 1.0,
        'sigma_t': {'type': 'gridvolume', 'grid': grid,
            'to_world': mi.ScalarTransform4f().scale(1.0)}}},
})
mi.render(scene, spp=1)
t = time.time(); img = mi.render(scene, spp=spp); dt = time.time() - t
n = 48*48*spp
print(f"mitsuba scalar_rgb threads={threads} spp={spp}: {dt:.3f} s, {n/dt/threads:.0f} samples/s/core, mean {float(np.mean(np.array(img))):.4f}")
