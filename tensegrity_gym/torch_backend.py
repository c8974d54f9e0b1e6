"""Re-exports: the torch backend (:mod:`tensegrity_gym.backends.torch`) under the module name it
had before; ``motor`` / ``advance`` are :func:`~tensegrity_gym.backends.torch.actuation.update_motor`
/ :func:`~tensegrity_gym.backends.torch.actuation.update_rate`."""
from .backends.torch.actuation import physics_inputs, update_motor, update_rate
from .backends.torch.contact import contact_forces, contact_step, contact_substep, init_contact_state
from .backends.torch.divergence import diverged
from .backends.torch.driver import accelerations, integrator_name, simulate, step, step_once, step_state
from .backends.torch.equations import (force_densities, nodal_forces, node_positions, node_velocities, project,
                                       sphere_drift, string_state, torch_stack3)
from .backends.torch.model import (PARAM_FIELDS, TorchModel, mass_moments, resolve_device, resolve_dtype,
                                   torch_model, torch_module, torch_params)

motor = update_motor
advance = update_rate
_torch = torch_module                 # the names the envs used
_integrator_name = integrator_name

__all__ = ["resolve_device", "resolve_dtype", "TorchModel", "torch_model", "torch_params", "mass_moments",
           "node_positions", "node_velocities", "string_state", "force_densities", "nodal_forces", "accelerations",
           "project", "sphere_drift", "step", "contact_forces", "contact_step", "contact_substep",
           "init_contact_state", "motor", "advance", "update_motor", "update_rate", "physics_inputs", "step_state",
           "simulate", "diverged", "PARAM_FIELDS", "step_once", "torch_stack3", "torch_module", "integrator_name"]
