"""Formats and datasets: exp-map, BVH, 3DPW and AMASS readers, skeletons and forward kinematics,
CMU and Human3.6M, meshes and their spectral bases, the cloth simulation, CMU motion on the Anny
body, and the one windowing routine every model and metric shares."""
