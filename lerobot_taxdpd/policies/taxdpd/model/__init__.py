"""Networks of the TAX-DPD goal predictor (plain PyTorch, no compiled extensions)."""
