"""Numerical building blocks below the physics: nothing here knows about drones or recordings."""
