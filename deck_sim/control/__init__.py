"""Control library beside the physics: prediction, tracking and planners (numpy and CasADi only)."""
