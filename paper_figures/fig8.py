"""Fig. 8: singular values of P·P̂⁻¹ for both models (P the true sampled plant), with the paper's ±7 dB band.

python paper_figures/fig8.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("fig8", __doc__)
