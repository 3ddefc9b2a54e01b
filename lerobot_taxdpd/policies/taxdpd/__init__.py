"""`--policy.type=taxdpd`: the TAX-DPD goal predictor (Dense GMM + disentangled point-cloud diffusion)."""
