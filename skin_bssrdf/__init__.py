"""skin_bssrdf."""
