"""Test problem sets as data: the non-stiff DETEST problems and the stiff set (Robertson,
Van der Pol, HIRES, a stiff linear system), each with its source and reference."""
