"""Physics core: vehicle, rigid-body dynamics (the paper's eq. 1), effects, identification."""
