"""Fig. 10: singular values of T(jω) − I under the MIMO inverse-model controller, both models.

python paper_figures/fig10.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("fig10", __doc__)
