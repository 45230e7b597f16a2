"""Active view selection: two-sided splat reliability, 2D GauSS-MI and the selector plug-ins."""
