"""Liffman, Chan & Hughes 1992's setting, shared by its three protocols
(lattice, sloped, drop): the time step, the loading run and each law's
parameters in it."""

# The paper's setting (Liffman, Chan & Hughes 1992, eq. 46 and the analytic model's
# assumptions) expressed for the hooke law: mg / (k_n sigma) = 1e-4, only normal
# forces between disks (mu = 0, no rotation), and ground friction above
# (k - 1) / (sqrt(3) (k + 1)) = 0.55 for k = 45.
PAPER_SETTING = {
    "layers": 45,
    "rotation": False,
    "dt": 1.0e-3,
    "ramp_steps": 20_000,
    "speed_tolerance": 1.0e-5,
    "max_steps": 400_000,
    "params": {
        "hooke": {"kn": 1.0e4, "gamma_n": 100.0, "mu": 0.0, "wall_mu": 1.0},
        # the same static set-up in reduced units: Hertz with a 4e-3 sigma base
        # overlap; Baxter's n = 36 law, whose long tail makes same-level
        # neighbours push apart with ~mg, needs disk friction for the lattice to
        # stand (so it is not the 1992 frictionless analytic pile)
        # the paper's own law: K_s from eq. 46; disk friction is viscous, so it
        # vanishes at rest and the ground's static well holds the base
        "liffman": {"ks": 1.0e4, "mu_static": 1.0},
        "lee-herrmann": {"kn": 1.0e5, "gamma_n": 100.0, "mu": 0.0, "wall_mu": 1.0},
        "baxter": {"n": 36.0, "r0": 1.2, "mu": 1.0, "wall_mu": 1.0},
    },
}
