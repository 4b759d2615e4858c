"""Measurements on a pile, in one namespace (`from jaxpile.measure import
analysis`; each lives in the module named for what it measures):

* `forces`: the forces on the base, the ground's or the substrate disks'
  (`base_forces`, `substrate_forces`; `base_load` traceable for `jax.grad`);
* `network`: the contact network, and each disk's strongest and weakest
  contact, the "lines of maximum and minimum force" of Liffman, Chan & Hughes
  1992, Figs. 10 and 16;
* `surface`: the surface profile h(x) and the angle of repose by the three
  methods of Lee & Herrmann 1993, sec. 3, also per flank of a symmetric heap
  (Baxter et al. 1997);
* `voidage`: the packing-fraction / voidage map, a cell-averaged version of the
  density maps of Baxter et al. 1997, Figs. 2, 5, 6 and 8;
* `energy`: the mean kinetic energy per disk over time (Lee & Herrmann 1993,
  Fig. 1(b)) and the step from which a series stays at rest.
"""

from jaxpile.measure.energy import kinetic_energy, kinetic_energy_series, mean_kinetic_energy, rest_index
from jaxpile.measure.forces import (BASES, BaseForces, BaseLoad, SubstrateForces, base_forces, base_load, force_unit,
                                    substrate_forces, traced_force_unit)
from jaxpile.measure.network import (ContactNetwork, ForceChains, contact_network, force_chains, force_chains_of,
                                     wall_partner)
from jaxpile.measure.surface import (ReposeAngles, SurfaceProfile, apex_x, mid_flank_angle, recorded_repose_angles,
                                     repose_angles, surface_profile, surface_profile_of)
from jaxpile.measure.voidage import (VoidageMap, disk_rectangle_overlap, packing_fraction, voidage_map,
                                     voidage_map_bytes, voidage_map_of)

__all__ = [
    "BASES",
    "BaseForces",
    "BaseLoad",
    "ContactNetwork",
    "ForceChains",
    "ReposeAngles",
    "SubstrateForces",
    "SurfaceProfile",
    "VoidageMap",
    "apex_x",
    "base_forces",
    "base_load",
    "contact_network",
    "disk_rectangle_overlap",
    "force_chains",
    "force_chains_of",
    "force_unit",
    "kinetic_energy",
    "kinetic_energy_series",
    "mean_kinetic_energy",
    "mid_flank_angle",
    "packing_fraction",
    "recorded_repose_angles",
    "repose_angles",
    "rest_index",
    "substrate_forces",
    "surface_profile",
    "surface_profile_of",
    "traced_force_unit",
    "voidage_map",
    "voidage_map_bytes",
    "voidage_map_of",
    "wall_partner",
]
