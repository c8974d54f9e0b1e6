"""Re-exports: the model and state (:mod:`tensegrity_gym.core.model`), geometry and energies
(:mod:`tensegrity_gym.physics.geometry`), accelerations, forces and projection
(:mod:`tensegrity_gym.physics.evaluate`) and the stable-step estimate
(:mod:`tensegrity_gym.physics.stability`), under the module name they had before."""
from .core.model import Model, Params, State, compile_model, default_params, initial_state
from .physics.evaluate import accelerations, force_densities, nodal_forces, project
from .physics.geometry import (angular_momentum, center_of_mass, configuration_matrix, connectivity,
                               constraint_violation, energy, kinetic_energy, linear_momentum, node_positions,
                               node_velocities, potential_energy, rod_length_drift, string_state)
from .physics.stability import DENSE_STABILITY_MAX_RODS, stable_step_estimate

__all__ = ["Model", "State", "compile_model", "Params", "default_params", "initial_state", "node_positions",
           "node_velocities", "string_state", "force_densities", "nodal_forces", "accelerations", "project", "energy",
           "kinetic_energy", "potential_energy", "linear_momentum", "angular_momentum", "center_of_mass",
           "rod_length_drift", "configuration_matrix", "connectivity", "constraint_violation",
           "stable_step_estimate", "DENSE_STABILITY_MAX_RODS"]
