"""Agents shipped with the package: SB3 zips with their JSON sidecars (see vnhc_gym.training.agents)."""
