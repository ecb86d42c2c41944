"""Impedance schemes of chapters 3 and 5 (task space, any URDF arm)."""
