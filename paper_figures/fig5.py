"""Fig. 5: singular values of T(jω) − I under SISO control G = c·g(s)·I (c = 1 and the 6 dB / 30° design-rule gain).

python paper_figures/fig5.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("fig5", __doc__)
