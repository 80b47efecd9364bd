"""planner: contact-implicit motion planning with the time-freezing reformulation."""
from .errors import InputError, PlannerError, SolveError
from .model import Robot, load_robot

__all__ = ["InputError", "PlannerError", "Robot", "SolveError", "load_robot"]
__version__ = "0.1.0"
