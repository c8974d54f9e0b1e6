"""Re-exports: ground contact (:mod:`tensegrity_gym.physics.contact`) under the module name it
had before; ``step`` is :func:`tensegrity_gym.physics.pipeline.contact_step`."""
from .physics.contact import (PER_COPY_FIELDS, PRM_FIELDS, ContactState, GroundContact, check_prm_rows,
                              contact_energy, contact_forces, contact_nodes, forces_inplace, init_contact_state,
                              set_copy_values, stable_step)
from .physics.pipeline import contact_step as step

__all__ = ["GroundContact", "ContactState", "init_contact_state", "contact_forces", "forces_inplace",
           "contact_energy", "stable_step", "step", "contact_nodes", "PRM_FIELDS", "PER_COPY_FIELDS",
           "set_copy_values", "check_prm_rows"]
