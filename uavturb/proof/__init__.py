"""The gap finder proven blind: concealed effects, the conditions it is tried under, the PySINDy peer, scoring."""
