"""Building blocks shared by the control schemes (task space, adaptation laws, filters, networks)."""
