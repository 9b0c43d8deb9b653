"""The answers drawn from a sweep: the cheapest (method, h) under a tolerance (tune),
a fixed step judged point by point (verdict), the stability margin, and export."""
