"""`python -m mjxrow.episode`: one batch of episodes → episodes.csv (mjxrow.rollout.cli)."""

from mjxrow.rollout.episode import main

if __name__ == "__main__":
    main()
