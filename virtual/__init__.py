"""Virtual devices: Monte Carlo spectrophotometer and goniophotometer behind the bench interface."""
