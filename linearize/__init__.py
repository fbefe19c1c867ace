"""Offline builder: gain databases from plant models."""
