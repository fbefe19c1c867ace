"""Numba kernels of the two-spool separate-flow turbofan gas path (see docs/turbofan.md).

Everything here takes plain float64 arrays: ``C`` the cycle/map constant vector (layout by the
index constants below, filled by :func:`models.turbofan.design_constants`), ``amb`` the inlet and
ambient condition ``[T2, P2, P0, V0, T0]``, ``h`` the 10 health modifiers. No Python objects.

Solver unknowns ``v``:
  unbalanced (mode 0): fan beta, bypass ratio, LPC beta, HPC beta, HPT PR, LPT PR     (6)
  trim       (mode 1): the 6 above + Wf / Wf_design, Nc / Nc_design                 (8)
Residuals: bypass nozzle, LPC, HPC, HPT, LPT and core nozzle flow errors (divided by the inlet
flow W2); in trim mode also the LP and HP shaft power imbalance divided by the turbine power.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

# ---- layout of the constant vector C ------------------------------------------------------------
CPA, GAMA, CPG, GAMG, RA, RG = 0, 1, 2, 3, 4, 5
LHV, ETA_B, DP_B, TREF = 6, 7, 8, 9
REC, DP_BYP, DP_DUCT, DP_CORE = 10, 11, 12, 13
F_CUST, F_HPT, F_LPT = 14, 15, 16
ETAM_LP, ETAM_HP, PEXT_LP, PEXT_HP = 17, 18, 19, 20
J_LP, J_HP = 21, 22
A_BYP, A_CORE, CV_BYP, CV_CORE, NOZ_EPS = 23, 24, 25, 26, 27
NF_D, NC_D, NLPC_D, NHPC_D, NHPT_D, NLPT_D = 28, 29, 30, 31, 32, 33
A3, WF_D, W2_D = 34, 35, 36
# compressor map blocks (13 each): Wc_s1 lnPRs1 aw ap s1 qs c1 c2 eta_pk n_pk ke_n ke_b b_pk
FAN, LPC, HPC = 40, 53, 66
M_WCS, M_LNPR, M_AW, M_AP, M_S1, M_QS, M_C1, M_C2, M_ETA, M_NPK, M_KEN, M_KEB, M_BPK = range(13)
# turbine map blocks (6 each): capacity scale, a_phi, eta_d, q_d, e_t, spare
HPT, LPT = 80, 86
T_CAP, T_APHI, T_ETA, T_QD, T_ET = range(5)
NC_CONST = 96

# ---- layout of the station/output vector s ------------------------------------------------------
(S_W2, S_T13, S_P13, S_WBYP, S_WCORE, S_T24, S_P24, S_W25, S_T3, S_P3, S_PS3, S_W3, S_T4, S_P4,
 S_W4, S_T45, S_P45, S_W48, S_T48, S_W5, S_T50, S_P50, S_FGB, S_FGC, S_FRAM, S_FN, S_PWF, S_PWL,
 S_PWH, S_PWHT, S_PWLT, S_DNF, S_DNC, S_SMF, S_SML, S_SMH, S_ETAF, S_ETAL, S_ETAH, S_ETAHT,
 S_ETALT, S_NF, S_NL, S_NH, S_NHT, S_NLT, S_WNB, S_WNC, S_PRF, S_PRL, S_PRH, S_PIH, S_PIL, S_BPR,
 S_WF, S_NFRPM, S_NCRPM, S_T5, S_WCF, S_WCL, S_WCH, S_P17, S_P7, S_T2) = range(64)
NS = 64

# ---- solver status codes ------------------------------------------------------------------------
OK, BAD_START, LINESEARCH, MAXIT, SINGULAR = 0, 1, 2, 3, 4
STATUS_TEXT = {OK: "converged", BAD_START: "the start point is outside the model's valid region",
               LINESEARCH: "the line search found no decrease (no solution nearby, or a singular map region)",
               MAXIT: "the iteration cap was reached", SINGULAR: "singular Jacobian"}

T_STD = 288.15
P_STD = 101325.0
RPM2RAD = 2.0 * math.pi / 60.0


@njit(cache=True, nogil=True)
def isa(alt, dT):
    """ISA static temperature (+ offset dT) and pressure at geometric altitude ``alt`` (m)."""
    if alt <= 11000.0:
        Ti = T_STD - 0.0065 * alt
        P = P_STD * (Ti / T_STD) ** 5.255877
    else:
        Ti = 216.65
        P = 22632.06 * math.exp(-9.80665 * (alt - 11000.0) / (287.05287 * 216.65))
    return Ti + dT, P


@njit(cache=True, nogil=True)
def ambient(alt, mach, dT, C, amb):
    """Fill amb = [T2, P2, P0, V0, T0]: inlet total conditions (ram recovery C[REC]) and ambient."""
    T0, P0 = isa(alt, dT)
    g = C[GAMA]
    f = 1.0 + 0.5 * (g - 1.0) * mach * mach
    amb[0] = T0 * f
    amb[1] = P0 * f ** (g / (g - 1.0)) * C[REC]
    amb[2] = P0
    amb[3] = mach * math.sqrt(g * C[RA] * T0)
    amb[4] = T0


@njit(cache=True, nogil=True)
def smin(a, b, eps):
    """Smooth minimum -eps ln(exp(-a/eps) + exp(-b/eps)) (analytic; written in its overflow-free
    form): below min(a, b) by eps ln 2 where a = b, by ~eps exp(-|a - b|/eps) away from it."""
    return min(a, b) - eps * math.log1p(math.exp(-abs(a - b) / eps))


@njit(cache=True, nogil=True)
def nozzle(W, Pt, Tt, Pamb, A, gam, cp, R, Cv, eps):
    """Convergent nozzle: (ideal flow through area A, gross thrust of flow W, ok).

    The exit pressure ratio is the smooth minimum of Pt/Pamb and the critical ratio, so the
    choked/unchoked transition is C-infinity (flow is exact to ~1e-4 outside a band of a few eps).
    """
    PR = Pt / Pamb
    if not (PR > 1.0 + 1e-9) or not (Tt > 0.0):
        return 0.0, 0.0, False
    PRc = (0.5 * (gam + 1.0)) ** (gam / (gam - 1.0))
    PRe = smin(PR, PRc, eps)
    if not (PRe > 1.0 + 1e-12):
        return 0.0, 0.0, False
    Ts = Tt * PRe ** (-(gam - 1.0) / gam)
    Ps = Pt / PRe
    V = math.sqrt(2.0 * cp * (Tt - Ts))
    Wn = Ps / (R * Ts) * V * A
    Fg = W * Cv * V + A * (Ps - Pamb)
    return Wn, Fg, True


@njit(cache=True, nogil=True)
def compressor(n, beta, C, o):
    """Compressor map at relative corrected speed n and beta: (Wc, PR, eta, stall margin %).

    Stall line at beta = 0: Wc_s(n) = Wc_s1 n^aw, ln PR_s(n) = ln PR_s1 n^ap. Along a speed line
    Wc = Wc_s(n) (1 + s1 n^-qs beta), ln PR = ln PR_s(n) (1 - c1 beta - c2 beta^2);
    eta = eta_pk exp(-ke_n (n - n_pk)^2 - ke_b (beta - b_pk)^2). Stall margin at constant
    corrected flow: SM = (PR_stall(Wc) / PR - 1) 100.
    """
    wcs = C[o + M_WCS]
    lnps = C[o + M_LNPR]
    aw = C[o + M_AW]
    ap = C[o + M_AP]
    s = C[o + M_S1] * n ** (-C[o + M_QS])
    wc = wcs * n ** aw * (1.0 + s * beta)
    g = 1.0 - C[o + M_C1] * beta - C[o + M_C2] * beta * beta
    lnpr = lnps * n ** ap * g
    dn = n - C[o + M_NPK]
    db = beta - C[o + M_BPK]
    eta = C[o + M_ETA] * math.exp(-C[o + M_KEN] * dn * dn - C[o + M_KEB] * db * db)
    sm = 0.0
    if wc > 0.0:
        ns = (wc / wcs) ** (1.0 / aw)
        sm = (math.exp(lnps * ns ** ap - lnpr) - 1.0) * 100.0
    return wc, math.exp(lnpr), eta, sm


@njit(cache=True, nogil=True)
def turbine(PR, n, gam, C, o):
    """Turbine map: (corrected flow capacity, isentropic efficiency).

    Capacity = cap sqrt(1 - PR^-a) (a smooth choking characteristic); efficiency from the blade
    to isentropic-spouting speed ratio r = n sqrt(q_d / q), q = 1 - PR^-((gam-1)/gam):
    eta = eta_d (2 r / (1 + r^2))^e.
    """
    q = 1.0 - PR ** (-(gam - 1.0) / gam)
    cap = C[o + T_CAP] * math.sqrt(1.0 - PR ** (-C[o + T_APHI]))
    r = n * math.sqrt(C[o + T_QD] / q)
    eta = C[o + T_ETA] * (2.0 * r / (1.0 + r * r)) ** C[o + T_ET]
    return cap, eta


@njit(cache=True, nogil=True, inline="always")
def turbine_stage(W, Tt, Pt, PR, n_rel, h_flow, h_eff, Wcool, Tcool, kg, cpa, cpg, Tref, C, o):
    """One turbine (map block o) at inlet flow W, Tt, Pt, pressure ratio PR, mechanical speed
    over design speed n_rel, then its cooling air Wcool (at Tcool) mixed in at the exit.

    Returns (map flow at the inlet conditions, exit Tt, exit Pt, power, mixed flow, mixed Tt,
    efficiency, corrected speed ratio).
    """
    th = Tt / T_STD
    nc = n_rel / math.sqrt(th)
    cap, eta = turbine(PR, nc, C[GAMG], C, o)
    cap *= 1.0 + h_flow
    eta *= 1.0 + h_eff
    Wmap = cap * (Pt / P_STD) / math.sqrt(th)
    Tout = Tt * (1.0 - eta * (1.0 - PR ** (-kg)))
    Pw = W * cpg * (Tt - Tout)
    Wmix = W + Wcool
    Tmix = Tref + (W * cpg * (Tout - Tref) + Wcool * cpa * (Tcool - Tref)) / (Wmix * cpg)
    return Wmap, Tout, Pt / PR, Pw, Wmix, Tmix, eta, nc


@njit(cache=True, nogil=True)
def gaspath(v, mode, Nf, Nc, Wf, amb, h, C, r, s):
    """Evaluate the component matching residuals r and stations s at unknowns v. Returns ok."""
    bf = v[0]
    bpr = v[1]
    bl = v[2]
    bh = v[3]
    pih = v[4]
    pil = v[5]
    if mode == 1:
        Wf = v[6] * C[WF_D]
        Nc = v[7] * C[NC_D]
    if not (bpr > 0.0 and pih > 1.0 + 1e-9 and pil > 1.0 + 1e-9 and Wf > 0.0 and Nc > 0.0
            and Nf > 0.0):
        return False
    cpa = C[CPA]
    cpg = C[CPG]
    ka = (C[GAMA] - 1.0) / C[GAMA]
    kg = (C[GAMG] - 1.0) / C[GAMG]
    Tref = C[TREF]
    T2 = amb[0]
    P2 = amb[1]
    P0 = amb[2]
    V0 = amb[3]
    # fan
    th2 = T2 / T_STD
    nf = Nf / math.sqrt(th2) / C[NF_D]
    wcf, prf, etaf, smf = compressor(nf, bf, C, FAN)
    wcf_h = wcf * (1.0 + h[1])
    etaf *= 1.0 + h[0]
    if not (wcf_h > 0.0 and etaf > 0.0 and prf > 0.0):
        return False
    W2 = wcf_h * (P2 / P_STD) / math.sqrt(th2)
    T13 = T2 * (1.0 + (prf ** ka - 1.0) / etaf)
    P13 = P2 * prf
    Pwf = W2 * cpa * (T13 - T2)
    Wbyp = W2 * bpr / (1.0 + bpr)
    Wcore = W2 / (1.0 + bpr)
    P17 = P13 * (1.0 - C[DP_BYP])
    Wnb, Fgb, ok = nozzle(Wbyp, P17, T13, P0, C[A_BYP], C[GAMA], cpa, C[RA], C[CV_BYP], C[NOZ_EPS])
    if not ok or not (T13 > 0.0):
        return False
    # LPC (booster) on the LP shaft
    th13 = T13 / T_STD
    nl = Nf / math.sqrt(th13) / C[NLPC_D]
    wcl, prl, etal, sml = compressor(nl, bl, C, LPC)
    wcl_h = wcl * (1.0 + h[3])
    etal *= 1.0 + h[2]
    if not (wcl_h > 0.0 and etal > 0.0):
        return False
    W21 = wcl_h * (P13 / P_STD) / math.sqrt(th13)
    T24 = T13 * (1.0 + (prl ** ka - 1.0) / etal)
    P24 = P13 * prl
    Pwl = W21 * cpa * (T24 - T13)
    if not (T24 > 0.0):
        return False
    # HPC
    P25 = P24 * (1.0 - C[DP_DUCT])
    th25 = T24 / T_STD
    nh = Nc / math.sqrt(th25) / C[NHPC_D]
    wch, prh, etah, smh = compressor(nh, bh, C, HPC)
    wch_h = wch * (1.0 + h[5])
    etah *= 1.0 + h[4]
    if not (wch_h > 0.0 and etah > 0.0):
        return False
    W25 = wch_h * (P25 / P_STD) / math.sqrt(th25)
    T3 = T24 * (1.0 + (prh ** ka - 1.0) / etah)
    P3 = P25 * prh
    Pwh = W25 * cpa * (T3 - T24)
    if not (T3 > 0.0):
        return False
    Ps3 = P3 - W25 * W25 * C[RA] * T3 / (2.0 * P3 * C[A3] * C[A3])
    W3 = W25 * (1.0 - C[F_CUST] - C[F_HPT] - C[F_LPT])
    # burner
    P4 = P3 * (1.0 - C[DP_B])
    W4 = W3 + Wf
    T4 = Tref + (W3 * cpa * (T3 - Tref) + C[ETA_B] * Wf * C[LHV]) / (W4 * cpg)
    if not (T4 > 0.0):
        return False
    # HPT, its cooling air mixed at the HPT exit (station 48)
    W4c, T45, P45, Pwht, W48, T48, etaht, nht = turbine_stage(W4, T4, P4, pih, Nc / C[NHPT_D], h[7], h[6],
                                                  C[F_HPT] * W25, T3, kg, cpa, cpg, Tref, C, HPT)
    if not (T45 > 0.0):
        return False
    # LPT, its cooling air mixed at the LPT exit (station 50)
    W48c, T5, P5, Pwlt, W5, T50, etalt, nlt = turbine_stage(W48, T48, P45, pil, Nf / C[NLPT_D], h[9], h[8],
                                                C[F_LPT] * W25, T3, kg, cpa, cpg, Tref, C, LPT)
    if not (T5 > 0.0):
        return False
    P7 = P5 * (1.0 - C[DP_CORE])
    Wnc, Fgc, ok = nozzle(W5, P7, T50, P0, C[A_CORE], C[GAMG], cpg, C[RG], C[CV_CORE], C[NOZ_EPS])
    if not ok:
        return False
    # residuals (flow errors / W2)
    r[0] = (Wbyp - Wnb) / W2
    r[1] = (Wcore - W21) / W2
    r[2] = (W21 - W25) / W2
    r[3] = (W4 - W4c) / W2
    r[4] = (W48 - W48c) / W2
    r[5] = (W5 - Wnc) / W2
    # shafts
    Pnet_lp = C[ETAM_LP] * Pwlt - Pwf - Pwl - C[PEXT_LP]
    Pnet_hp = C[ETAM_HP] * Pwht - Pwh - C[PEXT_HP]
    if mode == 1:
        r[6] = Pnet_lp / Pwlt
        r[7] = Pnet_hp / Pwht
    Fram = W2 * V0
    s[S_W2] = W2
    s[S_T13] = T13
    s[S_P13] = P13
    s[S_WBYP] = Wbyp
    s[S_WCORE] = Wcore
    s[S_T24] = T24
    s[S_P24] = P24
    s[S_W25] = W25
    s[S_T3] = T3
    s[S_P3] = P3
    s[S_PS3] = Ps3
    s[S_W3] = W3
    s[S_T4] = T4
    s[S_P4] = P4
    s[S_W4] = W4
    s[S_T45] = T45
    s[S_P45] = P45
    s[S_W48] = W48
    s[S_T48] = T48
    s[S_W5] = W5
    s[S_T50] = T50
    s[S_P50] = P5
    s[S_FGB] = Fgb
    s[S_FGC] = Fgc
    s[S_FRAM] = Fram
    s[S_FN] = Fgb + Fgc - Fram
    s[S_PWF] = Pwf
    s[S_PWL] = Pwl
    s[S_PWH] = Pwh
    s[S_PWHT] = Pwht
    s[S_PWLT] = Pwlt
    s[S_DNF] = Pnet_lp / (C[J_LP] * RPM2RAD * RPM2RAD * Nf)
    s[S_DNC] = Pnet_hp / (C[J_HP] * RPM2RAD * RPM2RAD * Nc)
    s[S_SMF] = smf
    s[S_SML] = sml
    s[S_SMH] = smh
    s[S_ETAF] = etaf
    s[S_ETAL] = etal
    s[S_ETAH] = etah
    s[S_ETAHT] = etaht
    s[S_ETALT] = etalt
    s[S_NF] = nf
    s[S_NL] = nl
    s[S_NH] = nh
    s[S_NHT] = nht
    s[S_NLT] = nlt
    s[S_WNB] = Wnb
    s[S_WNC] = Wnc
    s[S_PRF] = prf
    s[S_PRL] = prl
    s[S_PRH] = prh
    s[S_PIH] = pih
    s[S_PIL] = pil
    s[S_BPR] = bpr
    s[S_WF] = Wf
    s[S_NFRPM] = Nf
    s[S_NCRPM] = Nc
    s[S_T5] = T5
    s[S_WCF] = wcf
    s[S_WCL] = wcl
    s[S_WCH] = wch
    s[S_P17] = P17
    s[S_P7] = P7
    s[S_T2] = T2
    return True


# Newton bounds, step limits and finite-difference scales per unknown
_LO = np.array([-0.45, 0.2, -0.45, -0.45, 1.0005, 1.0005, 1e-3, 0.2])
_HI = np.array([3.5, 60.0, 3.5, 3.5, 40.0, 40.0, 6.0, 1.6])
_DMAX = np.array([0.4, 0.0, 0.4, 0.4, 0.0, 0.0, 0.0, 0.08])   # 0: relative limit below
_DREL = np.array([0.0, 0.3, 0.0, 0.0, 0.25, 0.25, 0.3, 0.0])


@njit(cache=True, nogil=True)
def _fd_step(v, j):
    if j == 1 or j == 6 or j == 7:
        return 1e-7 * max(abs(v[j]), 0.1)
    if j == 4 or j == 5:
        return 1e-7 * v[j]
    return 1e-7


@njit(cache=True, nogil=True)
def _maxabs(r, n):
    m = 0.0
    for i in range(n):
        a = abs(r[i])
        if not (a <= m):   # NaN-safe
            m = a
    return m


@njit(cache=True, nogil=True)
def newton(v, mode, Nf, Nc, Wf, amb, h, C, tol, maxit, s, J, reuse):
    """Damped Newton on the matching residuals, in place on v (and s = stations at the solution).

    Forward-difference Jacobian (recomputed each iteration unless ``reuse`` > 0 and the previous
    one in J still gives a contraction), step limits, bounds, backtracking on |r|. Returns
    (status, iterations, max |r|); status 0 = converged to max |r| < tol.
    """
    n = 6 if mode == 0 else 8
    r = np.empty(8)
    rt = np.empty(8)
    rj = np.empty(8)
    vt = np.empty(8)
    st = np.empty(NS)
    sj = np.empty(NS)
    for i in range(n, 8):
        r[i] = 0.0
    if not gaspath(v, mode, Nf, Nc, Wf, amb, h, C, r, s):
        return BAD_START, 0, np.inf
    rmax = _maxabs(r, n)
    have_J = reuse > 0
    for it in range(maxit):
        if rmax < tol:
            return OK, it, rmax
        fresh = not have_J
        if fresh:
            for j in range(n):
                for i in range(n):
                    vt[i] = v[i]
                dvj = _fd_step(v, j)
                vt[j] = v[j] + dvj
                okj = gaspath(vt, mode, Nf, Nc, Wf, amb, h, C, rj, sj)
                if not okj:
                    dvj = -dvj
                    vt[j] = v[j] + dvj
                    okj = gaspath(vt, mode, Nf, Nc, Wf, amb, h, C, rj, sj)
                    if not okj:
                        return BAD_START, it, rmax
                for i in range(n):
                    J[i, j] = (rj[i] - r[i]) / dvj
        Jn = J[:n, :n].copy()
        rhs = np.empty(n)
        for i in range(n):
            rhs[i] = -r[i]
        # LU with partial pivoting (no exceptions inside the kernel)
        piv_ok = True
        for k in range(n):
            p = k
            big = abs(Jn[k, k])
            for i in range(k + 1, n):
                if abs(Jn[i, k]) > big:
                    big = abs(Jn[i, k])
                    p = i
            if not (big > 1e-300):
                piv_ok = False
                break
            if p != k:
                for c in range(n):
                    tmp = Jn[k, c]
                    Jn[k, c] = Jn[p, c]
                    Jn[p, c] = tmp
                tmp = rhs[k]
                rhs[k] = rhs[p]
                rhs[p] = tmp
            for i in range(k + 1, n):
                f = Jn[i, k] / Jn[k, k]
                if f != 0.0:
                    for c in range(k, n):
                        Jn[i, c] -= f * Jn[k, c]
                    rhs[i] -= f * rhs[k]
        if not piv_ok:
            if not fresh:
                have_J = False
                continue
            return SINGULAR, it, rmax
        dv = np.empty(n)
        for i in range(n - 1, -1, -1):
            acc = rhs[i]
            for c in range(i + 1, n):
                acc -= Jn[i, c] * dv[c]
            dv[i] = acc / Jn[i, i]
        # step limits and bounds
        alpha = 1.0
        for i in range(n):
            if not np.isfinite(dv[i]):
                return SINGULAR, it, rmax
            lim = _DMAX[i] if _DMAX[i] > 0.0 else _DREL[i] * abs(v[i])
            if i == 4 or i == 5:
                lim = _DREL[i] * (v[i] - 1.0) + 0.02
            if abs(dv[i]) * alpha > lim:
                alpha = lim / abs(dv[i])
            if v[i] + alpha * dv[i] < _LO[i]:
                alpha = 0.9 * (_LO[i] - v[i]) / dv[i] if v[i] > _LO[i] else 0.0
            if v[i] + alpha * dv[i] > _HI[i]:
                alpha = 0.9 * (_HI[i] - v[i]) / dv[i] if v[i] < _HI[i] else 0.0
        if alpha <= 0.0:
            return LINESEARCH, it, rmax
        f0 = 0.0
        for i in range(n):
            f0 += r[i] * r[i]
        accepted = False
        for ls in range(14):
            for i in range(n):
                vt[i] = v[i] + alpha * dv[i]
            for i in range(n, 8):
                vt[i] = v[i]
            if gaspath(vt, mode, Nf, Nc, Wf, amb, h, C, rt, st):
                ft = 0.0
                for i in range(n):
                    ft += rt[i] * rt[i]
                rtm = _maxabs(rt, n)
                if ft < (1.0 - 1e-4 * alpha) * f0 or rtm < tol:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            if not fresh:     # stale Jacobian: recompute and retry
                have_J = False
                continue
            return LINESEARCH, it, rmax
        # with reuse, keep the Jacobian while it contracts well; otherwise refresh every iteration
        rnew = _maxabs(rt, n)
        have_J = reuse > 0 and rnew < 0.25 * rmax
        for i in range(n):
            v[i] = vt[i]
            r[i] = rt[i]
        for i in range(NS):
            s[i] = st[i]
        rmax = rnew
    if rmax < tol:
        return OK, maxit, rmax
    return MAXIT, maxit, rmax
