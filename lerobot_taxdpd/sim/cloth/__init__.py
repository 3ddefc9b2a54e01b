"""`cloth_hang`: a DEDO-style multi-hanger cloth task in pybullet, its scripted expert, data and evaluation."""
