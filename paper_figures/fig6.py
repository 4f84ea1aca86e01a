"""Fig. 6: singular values of the measured Z_H and of its paper-WLS and hapid-NLS models.

python paper_figures/fig6.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("fig6", __doc__)
