"""Plant models (plain code satisfying the Plant protocol; import neither pwl nor linearize)."""
