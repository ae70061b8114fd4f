"""The screens: what the dashboard and the map read (command form, estimate, airtime, status)."""
