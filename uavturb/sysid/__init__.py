"""System identification on recorded flights: aligned flight data, the paper's least squares for
the rotor constants and inertia, and the residual force (ground-truth turbulence)."""
