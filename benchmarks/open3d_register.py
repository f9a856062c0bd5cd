"""The one-shot Open3D script a practitioner would write for two scans (the comparison for ``rpmnet-register``):
read, voxel 2 mm, normals, FPFH, RANSAC, Tukey point-to-plane ICP, write the 4x4 transform.

    python benchmarks/open3d_register.py SRC REF OUT.txt [--voxel 0.002]
"""

import argparse

import numpy as np
import open3d as o3d

p = argparse.ArgumentParser()
p.add_argument("src")
p.add_argument("ref")
p.add_argument("out")
p.add_argument("--voxel", type=float, default=0.002)
a = p.parse_args()
reg = o3d.pipelines.registration
o3d.utility.random.seed(0)
clouds, features = [], []
for path in (a.src, a.ref):
    pc = o3d.io.read_point_cloud(path).voxel_down_sample(a.voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * a.voxel, max_nn=30))
    clouds.append(pc)
    features.append(reg.compute_fpfh_feature(pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * a.voxel, max_nn=100)))
d = 1.5 * a.voxel
ransac = reg.registration_ransac_based_on_feature_matching(
    clouds[0], clouds[1], features[0], features[1], True, d, reg.TransformationEstimationPointToPoint(False), 3,
    [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(d)],
    reg.RANSACConvergenceCriteria(100000, 0.999))
icp = reg.registration_icp(clouds[0], clouds[1], d, ransac.transformation,
                           reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=d)))
np.savetxt(a.out, icp.transformation, fmt="%.17g")
