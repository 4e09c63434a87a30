"""The paper's tensile test on its PLLA mat (Tables 2-3, Fig. 11 and 13) in one script.

Physics: a virtual PLLA mat (15 layers of 0.45 um fibers, 90 um square, volume fraction 0.19)
is pulled uniaxially at 5e-3 1/s to 30 % strain with its lateral sides held (F'22 = 1). Each
fiber is a slack/taut spring (E_b = 3 MPa wrinkled, E_t = 3 GPa once straight) that flows
plastically as d lambda_p / dt = a_p sinh(t / (b_p lambda_p^c_p)) with a_p = 1e-8 1/s,
b_p = 5 MPa, c_p = 0.5. The script prints the nominal stress P'11 and the paper's Eq. 17
stress [MPa] with the recruited and yielded fiber fractions, and writes the results folder.
Expect a linear response to about 3 % strain, yield, then nearly linear hardening.

Run:  python examples/tensile_plla.py [--size-ratio 200] [--layers 15] [--out plla_test]
"""

from __future__ import annotations

import argparse

import espin


def main(size_ratio: float = 200.0, layers: int = 15, max_strain: float = 0.30, steps: int = 30,
         out: str = "plla_test"):
    result = espin.simulate("plla", out, rve__size_ratio=size_ratio, rve__layers=layers,
                            loading__max_strain=max_strain, loading__steps=steps)
    print(f"{'strain':>7} {'P11 MPa':>8} {'Eq.17':>8} {'recruited':>9} {'yielded':>8}")
    for k in range(len(result.strain)):
        print(f"{result.strain[k]:7.3f} {result.stress('nominal')[k]:8.3f} "
              f"{result.stress('paper')[k]:8.3f} {result.recruited_fraction[k]:9.3f} "
              f"{result.yielded_fraction[k]:8.3f}")
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-ratio", type=float, default=200.0)
    parser.add_argument("--layers", type=int, default=15)
    parser.add_argument("--out", default="plla_test")
    args = parser.parse_args()
    main(args.size_ratio, args.layers, out=args.out)
