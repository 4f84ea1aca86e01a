"""summary.md and summary.json: the paper's reported numbers next to ours, for both fits.

python paper_figures/summary.py [--out out/paper]
"""

from _common import main

if __name__ == "__main__":
    main("summary", __doc__)
