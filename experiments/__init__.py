"""Hydra entry points. ``python -m experiments.run experiment=<name>`` runs one study."""
