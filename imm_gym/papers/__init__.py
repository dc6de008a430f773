"""What reproduces a source document: the TIP-IMM paper's Table 2 (000), the heterogeneous
IMM-EKF system (002) and the BBSCA-tuned CV/CA/CT system (003)."""
