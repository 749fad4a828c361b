"""quadwind_trl: wind-aware RL flight control of a small quadrotor on TorchRL."""
__version__ = "0.1.0"
