"""The simulated world's ground truth and the scoring against it, shared by the tests and the
benchmarks (tools/bench): the true maps of a scene, the vehicle's own check of a driven track,
the perception ceiling, the fusion's RMSE per range band, synthetic inputs whose truth is known
and the reference implementations the fast kernels are held to.

It sits above the server in the layers (it reads the simulator through ``drivers.sim`` and
judges with the workflows' algorithms, which ``drivers`` may not import, and one of its scans
runs a real server); nothing but the tests and the benchmarks imports it.
"""
