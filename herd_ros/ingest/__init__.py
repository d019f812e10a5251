"""The ingest path: WGS84 geodesy -> per-collar Kalman filtering with gating -> one herd clock."""
