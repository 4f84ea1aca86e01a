"""Fig. 7: singular values of the measured Z_T and of its paper-WLS and hapid-NLS models.

python paper_figures/fig7.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("fig7", __doc__)
