"""Fig. 9: characteristic loci of P(z)G(z) for the MIMO controller — Nyquist plane and Bode.

python paper_figures/fig9.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("fig9", __doc__)
