"""Re-export: the roll task's terms live in :mod:`tensegrity_gym.tasks.roll`."""
from ..tasks.roll import roll_state_observation, roll_step_terms, sum_squares

__all__ = ["sum_squares", "roll_step_terms", "roll_state_observation"]
