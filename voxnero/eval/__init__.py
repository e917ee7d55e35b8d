"""Evaluation: Chamfer distance (NeRO protocol), normal error, image metrics, reports."""
