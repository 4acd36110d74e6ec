"""The paper's experiments and figures, the free family's experiments (beyond the paper) and
the report; the AL and TL sweep adapters.
"""
