"""Experiment drivers above the closed loop: score finished run folders (`run_eval`), fly scenes x
methods x seeds (`sweep`) and write the paper's tables and figures from them (`report`)."""
