"""Force control through a dynamic constraint (chapter 4) and mass-chain position control (appendix C)."""
