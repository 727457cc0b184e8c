/* Thin C shim over SuiteSparse CHOLMOD for the sparse dual active-set projection
 * (src/solvers/sparse_as/, Fortran interfaces in cr_cholmod.f90 beside it).
 *
 * One handle holds a symmetric matrix M [n, n] (upper triangle, compressed columns, 0-based,
 * rows sorted within each column), its symbolic analysis (fill-reducing ordering and pattern)
 * and a simplicial LDL' factor of the "active" matrix
 *     A = M restricted to the active rows and columns, identity on the other rows,
 * which the caller modifies with row additions (cholmod_rowadd) and deletions (several rows in
 * one multiple-rank cholmod_updown, cr_chol_rowdel) as the active set changes. Every function
 * returns 0 on success and a nonzero code otherwise; cr_chol_message gives the reason. The shim
 * allocates nothing the caller sees; all indices at this interface are 0-based and in the
 * caller's (unpermuted) numbering.
 */
#include <stdlib.h>
#include <string.h>
#include <stdio.h>
#include <math.h>
#include <suitesparse/cholmod.h>

typedef struct {
  cholmod_common c;
  int started;
  int n;
  cholmod_sparse *m;      /* pattern of M as analysed, upper, stype = 1 (it bounds later values) */
  double *v;              /* current values of M on the analysed pattern (m's layout; zero
                           * where cr_chol_set_analysed_values gave a zero) [nnz(m)] */
  int *ss;                /* the entry of m each entry of pm comes from [nnz(m)] */
  cholmod_factor *sym;    /* symbolic analysis of M */
  cholmod_factor *l;      /* numeric LDL' factor of the active matrix */
  int lstale;             /* l belongs to this analysis but not to the current values (after
                           * cr_chol_set_analysed_values): no factor for the solve, the row
                           * updates and the pivots; cr_chol_factor refactorises it in place */
  cholmod_sparse *fa;     /* the active matrix handed to cholmod_rowfac (kept per analysis) */
  cholmod_sparse *r;      /* rowadd column [n, 1] */
  int *iperm;             /* position of each row in the factor [n] */
  int *active;            /* current active flags [n] */
  int *inset;             /* rows of the analysed set W: the only rows that may be active [n] */
  double *yw;             /* zero work vector of the Schur-complement test [n] */
  double *xw;             /* work vector of the solve, factor order [n] */
  cholmod_sparse *pm;     /* pattern of P M P' (upper, factor order, rows increasing in each
                           * column), for the row subtrees and the factorisation */
  int *parent;            /* elimination tree of P M P' [n] */
  int *mk, *stk;          /* marks (zero between calls) and a stack of the Schur test [n]
                           * (mk also flags the rows of a deletion) */
  cholmod_sparse *cu;     /* the update C of a row deletion [n, nt] (grown as needed) */
  cholmod_sparse *rpat;   /* pattern bound of a row of L (its row subtree) in a deletion [n, 1] */
  long n_schur_scan;      /* Schur tests whose reach missed a fill (done by the scan) */
  long n_bounded;         /* factorisations redone with bounded pivots (an exact zero pivot) */
  int nrow;               /* the caller's rows (cr_chol_set_rows; n after an analysis) */
  int *rowof;             /* caller's row at each factor position, -1 for none [n] */
  int *slotof;            /* slot of each of the caller's rows, -1 for none [nrow] (NULL: the
                           * identity, as after an analysis) */
  int *rs;                /* work [n + 1] */
  int tail_next;          /* the next free tail slot (tail slots: the last ones of an analysis,
                           * empty there and ordered last, in slot order; cr_chol_add_slot gives
                           * them to rows whose pattern the analysis did not know); n: none */
  int *apos, napos;       /* active factor positions, ascending [n] (the solve visits only
                           * these; the others are identity rows and, in the work vector
                           * xw, stay zero) */
  char msg[256];
} cr_chol_t;

static int fail(cr_chol_t *h, int code, const char *what) {
  snprintf(h->msg, sizeof h->msg, "CHOLMOD %s failed (status %d, n = %d)", what, h->c.status, h->n);
  return code;
}

/* A factor of the current values: a numeric factor exists and no new values came since it
 * was computed (cr_chol_set_analysed_values marks it stale until cr_chol_factor). */
static int have_factor(const cr_chol_t *h) { return h->l && !h->lstale; }

static void release(cr_chol_t *h) {
  if (!h->started) return;
  if (h->m) cholmod_free_sparse(&h->m, &h->c);
  free(h->v); h->v = NULL;
  free(h->ss); h->ss = NULL;
  if (h->sym) cholmod_free_factor(&h->sym, &h->c);
  if (h->l) cholmod_free_factor(&h->l, &h->c);
  h->lstale = 0;
  if (h->fa) cholmod_free_sparse(&h->fa, &h->c);
  if (h->r) cholmod_free_sparse(&h->r, &h->c);
  free(h->iperm); h->iperm = NULL;
  free(h->active); h->active = NULL;
  free(h->inset); h->inset = NULL;
  free(h->yw); h->yw = NULL;
  free(h->xw); h->xw = NULL;
  if (h->pm) cholmod_free_sparse(&h->pm, &h->c);
  if (h->rpat) cholmod_free_sparse(&h->rpat, &h->c);
  if (h->cu) cholmod_free_sparse(&h->cu, &h->c);
  free(h->parent); h->parent = NULL;
  free(h->mk); h->mk = NULL;
  free(h->stk); h->stk = NULL;
  free(h->rowof); h->rowof = NULL;
  free(h->apos); h->apos = NULL; h->napos = 0;
  free(h->rs); h->rs = NULL;
  free(h->slotof); h->slotof = NULL;
  h->nrow = 0;
  h->tail_next = 0;
  h->n = 0;
}

/* Create a handle (*hp = NULL on failure). */
int cr_chol_new(void **hp) {
  cr_chol_t *h = calloc(1, sizeof(cr_chol_t));
  *hp = NULL;
  if (!h) return 1;
  if (!cholmod_start(&h->c)) { free(h); return 2; }
  h->started = 1;
  h->c.supernodal = CHOLMOD_SIMPLICIAL;  /* row add/delete need a simplicial LDL' factor */
  h->c.final_ll = 0;
  h->c.print = 0;
  h->c.error_handler = NULL;
  h->msg[0] = '\0';
  *hp = h;
  return 0;
}

void cr_chol_free(void **hp) {
  cr_chol_t *h = (cr_chol_t *)(*hp);
  if (!h) return;
  release(h);
  cholmod_finish(&h->c);
  free(h);
  *hp = NULL;
}

/* Copy the last message into buf [len] (blank padded, for Fortran). */
void cr_chol_message(void *hp, char *buf, int len) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int i, k = (int)strlen(h->msg);
  for (i = 0; i < len; i++) buf[i] = i < k ? h->msg[i] : ' ';
}

/* The pattern of P M P' (upper triangle, factor order) and its elimination tree. Every factor
 * this handle holds is the LDL' factor of a principal submatrix of M (identity elsewhere) in
 * the same ordering, so its pattern, even after row additions and deletions, lies inside the
 * symbolic factor of P M P': the row subtree of row k of that tree (cholmod_row_subtree) is an
 * upper bound of the pattern of row k of L, which lets cholmod_rowdel skip its O(nnz(L)) scan. */
static int sorted_upper(cr_chol_t *h);

static int permuted_etree(cr_chol_t *h) {
  int n = h->n, rc, *mp = (int *)h->m->p;
  h->pm = cholmod_allocate_sparse(n, n, mp[n] > 0 ? mp[n] : 1, 1, 1, 1, CHOLMOD_PATTERN, &h->c);
  h->parent = malloc((size_t)(n > 0 ? n : 1) * sizeof(int));
  h->mk = calloc((size_t)(n > 0 ? n : 1), sizeof(int));
  h->stk = malloc((size_t)(n > 0 ? n : 1) * sizeof(int));
  h->rpat = cholmod_allocate_sparse(n, 1, n > 0 ? n : 1, 0, 1, 0, CHOLMOD_PATTERN, &h->c);
  if (!h->pm || !h->parent || !h->rpat || !h->mk || !h->stk) {
    snprintf(h->msg, sizeof h->msg, "out of memory (elimination tree, n = %d)", n);
    return 23;
  }
  /* the pattern of P M P' is that of the sorted upper triangle */
  rc = sorted_upper(h);
  if (rc != 0) return rc;
  h->pm->sorted = 1;
  if (!cholmod_etree(h->pm, h->parent, &h->c) || h->c.status < CHOLMOD_OK)
    return fail(h, 24, "etree");
  return 0;
}

/* The upper triangle of P M P' by columns with the rows of each column increasing (pm, also
 * the pattern of the elimination tree) and the entry of M each comes from (ss): the entries (a, k), a <= k factor positions, are
 * bucketed by a, then moved to column k in increasing a (entries below the diagonal of M are
 * ignored, as CHOLMOD does for a symmetric-upper matrix). cr_chol_factor gathers the active
 * matrix from it in one pass, in the form cholmod_rowfac takes. */
static int sorted_upper(cr_chol_t *h) {
  int n = h->n, j, q, a, b, k, e, *mp = (int *)h->m->p, *mi = (int *)h->m->i, *ip = h->iperm;
  int *rs = h->rs, *cnt = h->stk, *tk, *tq, *sp = (int *)h->pm->p, *si = (int *)h->pm->i;
  for (k = 0; k <= n; k++) rs[k] = 0;
  for (j = 0; j < n; j++)
    for (q = mp[j]; q < mp[j + 1]; q++) {
      if (mi[q] > j) continue;
      a = ip[mi[q]]; b = ip[j];
      rs[(a < b ? a : b) + 1]++;
    }
  for (k = 0; k < n; k++) { rs[k + 1] += rs[k]; cnt[k] = rs[k]; }
  e = rs[n];
  tk = malloc((size_t)(e > 0 ? e : 1) * sizeof(int));
  tq = malloc((size_t)(e > 0 ? e : 1) * sizeof(int));
  if (!tk || !tq) {
    free(tk); free(tq);
    snprintf(h->msg, sizeof h->msg, "out of memory (sorted upper triangle, n = %d)", n);
    return 5;
  }
  /* by rows: the column of each entry (tk) and the entry of M (tq) */
  for (j = 0; j < n; j++)
    for (q = mp[j]; q < mp[j + 1]; q++) {
      if (mi[q] > j) continue;
      a = ip[mi[q]]; b = ip[j];
      if (a > b) { k = a; a = b; } else k = b;
      tk[cnt[a]] = k; tq[cnt[a]] = q; cnt[a]++;
    }
  /* by columns, rows increasing */
  for (k = 0; k < n; k++) cnt[k] = 0;
  for (q = 0; q < e; q++) cnt[tk[q]]++;
  sp[0] = 0;
  for (k = 0; k < n; k++) { sp[k + 1] = sp[k] + cnt[k]; cnt[k] = sp[k]; }
  for (a = 0; a < n; a++)
    for (q = rs[a]; q < rs[a + 1]; q++) {
      k = tk[q];
      si[cnt[k]] = a; h->ss[cnt[k]] = tq[q]; cnt[k]++;
    }
  for (k = 0; k < n; k++) cnt[k] = 0;
  free(tk); free(tq);
  return 0;
}

/* Set M [n, n] (upper triangle, colptr [n+1], rowind and val [colptr[n]], 0-based, each
 * column's rows sorted) and analyse its pattern. perm [n] (0-based) is the ordering to use,
 * or NULL for AMD. inset [n] (or NULL: all rows) marks the rows that may become active; M
 * must hold every entry between two such rows (the caller drops the others, so that the
 * analysis is that of the rows that can become active); rowadd and factor refuse other rows.
 * The last ntail slots (0 <= ntail <= n) are tail slots: their columns must be empty; the
 * ordering puts them last, in slot order (with perm == NULL: AMD on the other slots), and
 * cr_chol_add_slot hands them, one by one, to rows that the analysis did not know. */
static int analyze(cr_chol_t *h, int n, const int *colptr, const int *rowind, const double *val,
                   const int *perm, const int *inset, int ntail);

int cr_chol_analyze(void *hp, int n, const int *colptr, const int *rowind, const double *val,
                    const int *perm, const int *inset, int ntail) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int rc = analyze(h, n, colptr, rowind, val, perm, inset, ntail);
  /* a failure leaves no half-built analysis: every later call refuses until the next one */
  if (rc) release(h);
  return rc;
}

static int analyze(cr_chol_t *h, int n, const int *colptr, const int *rowind, const double *val,
                   const int *perm, const int *inset, int ntail) {
  int nz = colptr[n], j, *p, *ip, nh = n - ntail, *tperm = NULL;
  release(h);
  if (ntail < 0 || ntail > n || colptr[nh] != nz) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_analyze: %d tail slots of %d (their columns must be empty)", ntail, n);
    return 35;
  }
  h->n = n;
  h->m = cholmod_allocate_sparse(n, n, nz > 0 ? nz : 1, 1, 1, 1, CHOLMOD_PATTERN, &h->c);
  if (!h->m) return fail(h, 3, "allocate_sparse (M)");
  memcpy(h->m->p, colptr, (size_t)(n + 1) * sizeof(int));
  memcpy(h->m->i, rowind, (size_t)nz * sizeof(int));
  if (ntail > 0 && !perm) {
    /* AMD on the leading nh slots (their columns hold every entry: a view of m), tails last */
    cholmod_sparse head = *h->m;
    head.nrow = (size_t)nh; head.ncol = (size_t)nh;
    tperm = malloc((size_t)n * sizeof(int));
    if (!tperm) { snprintf(h->msg, sizeof h->msg, "out of memory (n = %d)", n); return 5; }
    if (nh > 0 && (!cholmod_amd(&head, NULL, 0, tperm, &h->c) || h->c.status < CHOLMOD_OK)) {
      free(tperm); return fail(h, 4, "amd (leading slots)");
    }
    for (j = nh; j < n; j++) tperm[j] = j;
    perm = tperm;
  }
  if (perm) {
    h->c.nmethods = 1; h->c.method[0].ordering = CHOLMOD_GIVEN; h->c.postorder = 0;
    h->sym = cholmod_analyze_p(h->m, (int *)perm, NULL, 0, &h->c);
  } else {
    h->c.nmethods = 1; h->c.method[0].ordering = CHOLMOD_AMD; h->c.postorder = 0;
    h->sym = cholmod_analyze(h->m, &h->c);
  }
  free(tperm);
  if (!h->sym || h->c.status < CHOLMOD_OK) return fail(h, 4, "analyze");
  h->iperm = malloc((size_t)(n > 0 ? n : 1) * sizeof(int));
  h->active = calloc((size_t)(n > 0 ? n : 1), sizeof(int));
  h->inset = malloc((size_t)(n > 0 ? n : 1) * sizeof(int));
  if (!h->inset) { snprintf(h->msg, sizeof h->msg, "out of memory (n = %d)", n); return 5; }
  for (j = 0; j < n; j++) h->inset[j] = inset ? inset[j] : 1;
  h->yw = calloc((size_t)(n > 0 ? n : 1), sizeof(double));
  if (!h->iperm || !h->active || !h->yw) { snprintf(h->msg, sizeof h->msg, "out of memory (n = %d)", n); return 5; }
  p = (int *)h->sym->Perm; ip = h->iperm;
  for (j = 0; j < n; j++) ip[p[j]] = j;
  h->r = cholmod_allocate_sparse(n, 1, n > 0 ? n : 1, 1, 1, 0, CHOLMOD_REAL, &h->c);
  if (!h->r) return fail(h, 6, "allocate (work space)");
  h->xw = calloc((size_t)(n > 0 ? n : 1), sizeof(double));
  h->rowof = malloc((size_t)(n > 0 ? n : 1) * sizeof(int));
  h->apos = malloc((size_t)(n > 0 ? n : 1) * sizeof(int));
  h->napos = 0;
  h->rs = malloc((size_t)(n + 1) * sizeof(int));
  h->ss = malloc((size_t)(nz > 0 ? nz : 1) * sizeof(int));
  if (!h->xw || !h->rowof || !h->apos || !h->rs || !h->ss) {
    snprintf(h->msg, sizeof h->msg, "out of memory (n = %d)", n); return 5;
  }
  for (j = 0; j < n; j++) h->rowof[j] = p[j];
  h->nrow = n;
  free(h->slotof); h->slotof = NULL;
  for (j = nh; j < n; j++)
    if (ip[j] != j) { snprintf(h->msg, sizeof h->msg, "cr_chol_analyze: tail slot %d not ordered last", j + 1); return 36; }
  h->tail_next = nh;
  j = permuted_etree(h);
  if (j != 0) return j;
  /* the values, after the work of the pattern is freed (a lower peak of memory) */
  h->v = malloc((size_t)(nz > 0 ? nz : 1) * sizeof(double));
  if (!h->v) { snprintf(h->msg, sizeof h->msg, "out of memory (n = %d)", n); return 5; }
  memcpy(h->v, val, (size_t)nz * sizeof(double));
  return 0;
}

/* Room for need entries in the pattern a and in its companion array *side (elements of elem
 * bytes, one per entry, allocated with malloc): both grow by half when short. */
static int room(cr_chol_t *h, cholmod_sparse *a, void **side, size_t elem, size_t need, const char *what) {
  size_t cap;
  void *p;
  if (need <= a->nzmax) return 0;
  cap = need + need / 2 + 16;
  /* the companion first: a.nzmax, grown last, never promises room that *side lacks */
  p = realloc(*side, cap * elem);
  if (!p) { snprintf(h->msg, sizeof h->msg, "out of memory (%s, %zu entries)", what, cap); return 5; }
  *side = p;
  if (!cholmod_reallocate_sparse(cap, a, &h->c) || h->c.status < CHOLMOD_OK) {
    snprintf(h->msg, sizeof h->msg, "CHOLMOD reallocate_sparse (%s) failed (status %d, n = %d)", what,
             h->c.status, h->n);
    return 41;
  }
  return 0;
}

/* Give the next tail slot s (s = tail_next, 0-based) to the caller's row `row` (0-based, a row
 * without a slot). Its column of the upper triangle of M: rows [nz] (slots, increasing, every
 * one below s but the last, which is s itself: the diagonal) and val [nz]. The analysed
 * pattern and values, the pattern of P M P' with its map to M, and the elimination tree grow
 * by that column; as s is the last slot holding a row and is ordered after every such slot,
 * the tree of the grown matrix is the old one with s made the parent of the roots of the
 * subtrees that hold its neighbours (later tail slots are isolated). So the row-subtree bound
 * of every row deletion stays valid. The factor is not touched: slot s is an identity row
 * until cr_chol_rowadd (which finds the fill of the new row itself). */
int cr_chol_add_slot(void *hp, int s, int nz, const int *rows, const double *val, int row) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int n = h->n, q, j, a, r, ps, e0, rc, *mp, *sp, *ord;
  if (!h->sym || !h->m || !h->pm) { snprintf(h->msg, sizeof h->msg, "cr_chol_add_slot before cr_chol_analyze"); return 37; }
  if (s != h->tail_next || s >= n) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_add_slot: slot %d is not the next free tail slot (%d of %d)", s + 1,
             h->tail_next + 1, n);
    return 38;
  }
  if (nz < 1 || rows[nz - 1] != s || row < 0 || row >= h->nrow) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_add_slot: column of slot %d must end at its diagonal (row %d)", s + 1, row + 1);
    return 39;
  }
  for (q = 0; q + 1 < nz; q++)
    if (rows[q] < 0 || rows[q] >= s || (q > 0 && rows[q] <= rows[q - 1])) {
      snprintf(h->msg, sizeof h->msg, "cr_chol_add_slot: column of slot %d: rows not increasing below it", s + 1);
      return 39;
    }
  if (!h->slotof || h->slotof[row] >= 0) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_add_slot: row %d already has a slot", row + 1);
    return 40;
  }
  /* room first (a failure leaves the analysis as it was), then the analysed pattern and
   * values: column s (the columns after it are empty) */
  mp = (int *)h->m->p;
  e0 = mp[s];
  ps = h->iperm[s];
  sp = (int *)h->pm->p;
  rc = room(h, h->m, (void **)&h->v, sizeof(double), (size_t)e0 + (size_t)nz, "M");
  if (rc) return rc;
  rc = room(h, h->pm, (void **)&h->ss, sizeof(int), (size_t)sp[ps] + (size_t)nz, "P M P'");
  if (rc) return rc;
  mp = (int *)h->m->p; sp = (int *)h->pm->p;   /* (reallocation moves only i and x) */
  for (q = 0; q < nz; q++) { ((int *)h->m->i)[e0 + q] = rows[q]; h->v[e0 + q] = val[q]; }
  for (j = s + 1; j <= n; j++) mp[j] = e0 + nz;
  /* P M P': column ps = position of s (its neighbours' positions, increasing, then ps) */
  ord = h->stk;   /* (position, entry of m) pairs sorted by position: insertion sort */
  for (q = 0; q + 1 < nz; q++) {
    int pos = h->iperm[rows[q]], k = q;
    while (k > 0 && h->iperm[rows[ord[k - 1]]] > pos) { ord[k] = ord[k - 1]; k--; }
    ord[k] = q;
  }
  ord[nz - 1] = nz - 1;
  for (q = 0; q < nz; q++) {
    ((int *)h->pm->i)[sp[ps] + q] = h->iperm[rows[ord[q]]];
    h->ss[sp[ps] + q] = e0 + ord[q];
  }
  for (j = ps + 1; j <= n; j++) sp[j] = sp[ps] + nz;
  /* the elimination tree */
  for (q = 0; q + 1 < nz; q++) {
    a = h->iperm[rows[q]];
    for (r = a; h->parent[r] >= 0 && h->parent[r] != ps; r = h->parent[r]) ;
    if (h->parent[r] < 0 && r != ps) h->parent[r] = ps;
  }
  /* the caller's row now lives at position ps */
  h->rowof[ps] = row;
  h->slotof[row] = s;
  h->inset[s] = 1;
  h->tail_next++;
  return 0;
}

/* Tail slots left (cr_chol_add_slot). */
int cr_chol_tail_free(void *hp) {
  cr_chol_t *h = (cr_chol_t *)hp;
  return h->sym ? h->n - h->tail_next : 0;
}

/* New values of M on the stored analysis, on the analysed pattern itself: val [nz], nz the
 * entries handed to cr_chol_analyze, in their order (zero where the caller has no entry now).
 * The current numeric factor is stale from here on (see have_factor); cr_chol_factor
 * refactorises it in place. */
int cr_chol_set_analysed_values(void *hp, int nz, const double *val) {
  cr_chol_t *h = (cr_chol_t *)hp;
  if (!h->sym || !h->m) { snprintf(h->msg, sizeof h->msg, "cr_chol_set_analysed_values before cr_chol_analyze"); return 33; }
  if (nz != ((int *)h->m->p)[h->n]) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_set_analysed_values: %d values, %d analysed entries", nz,
             ((int *)h->m->p)[h->n]);
    return 34;
  }
  memcpy(h->v, val, (size_t)nz * sizeof(double));
  /* the factor's storage is kept for the next cr_chol_factor (refactorised in place) */
  if (h->l) h->lstale = 1;
  memset(h->active, 0, (size_t)h->n * sizeof(int));
  h->napos = 0;
  return 0;
}

/* The caller's rows from now on: map [nrow] (0-based slot of each row, -1 for none; slots
 * distinct, checked by the caller). The solve and cr_chol_add_slot use it (the other calls
 * get slots). */
int cr_chol_set_rows(void *hp, int nrow, const int *map) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int i, k;
  if (!h->sym) { snprintf(h->msg, sizeof h->msg, "cr_chol_set_rows before cr_chol_analyze"); return 32; }
  free(h->slotof);
  h->slotof = malloc((size_t)(nrow > 0 ? nrow : 1) * sizeof(int));
  if (!h->slotof) { snprintf(h->msg, sizeof h->msg, "out of memory (nrow = %d)", nrow); return 5; }
  /* the factor's positions now name other rows: refactorise before the next solve */
  if (h->l) h->lstale = 1;
  for (k = 0; k < h->n; k++) h->rowof[k] = -1;
  for (i = 0; i < nrow; i++) {
    h->slotof[i] = map[i];
    if (map[i] >= 0) h->rowof[h->iperm[map[i]]] = i;
  }
  h->nrow = nrow;
  return 0;
}

/* Predicted entries of the factor of the whole M (sum of the symbolic column counts). */
double cr_chol_symbolic_nnz(void *hp) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int j, *cc;
  double s = 0.0;
  if (!h->sym || !h->sym->ColCount) return 0.0;
  cc = (int *)h->sym->ColCount;
  for (j = 0; j < h->n; j++) s += cc[j];
  return s;
}

/* The ordering in use: perm [n] (0-based, perm[k] = row at position k). */
int cr_chol_perm(void *hp, int *perm) {
  cr_chol_t *h = (cr_chol_t *)hp;
  if (!h->sym) { snprintf(h->msg, sizeof h->msg, "cr_chol_perm before cr_chol_analyze"); return 22; }
  memcpy(perm, h->sym->Perm, (size_t)h->n * sizeof(int));
  return 0;
}

/* Factorise A = M on the rows with active[i] != 0, identity elsewhere (numeric refactorisation
 * on the stored analysis; the previous factor is discarded). A is built directly in factor
 * order (upper triangle of P A P', the form cholmod_rowfac works on), so that CHOLMOD does not
 * permute and transpose it twice as cholmod_factorize would; the arithmetic is the same. */
int cr_chol_factor(void *hp, const int *active, int pack_min) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int n = h->n, j, k, e, a, nz = 0, *pa, *ia, *actp, *pp, *sp, *si;
  double *xa, beta[2] = {0.0, 0.0}, dmax = 0.0;
  cholmod_sparse *A;
  if (!h->sym) { snprintf(h->msg, sizeof h->msg, "cr_chol_factor before cr_chol_analyze"); return 7; }
  for (j = 0; j < n; j++)
    if (active[j] && !h->inset[j]) {
      snprintf(h->msg, sizeof h->msg, "cr_chol_factor: row %d is active but outside the analysed set", j + 1);
      return 26;
    }
  /* from here on a failure leaves no usable factor (the active flags change below) */
  h->lstale = 1;
  memcpy(h->active, active, (size_t)n * sizeof(int));
  sp = (int *)h->pm->p; si = (int *)h->pm->i;
  pp = (int *)h->sym->Perm;
  actp = h->rs;   /* active flag of each factor position */
  for (k = 0; k < n; k++) actp[k] = active[pp[k]] != 0;
  /* room: the analysed columns of the active positions, one entry for each other one; the
   * matrix is kept with the analysis, sized for every position active */
  for (k = 0; k < n; k++) nz += actp[k] ? sp[k + 1] - sp[k] : 1;
  if (h->fa && h->fa->nzmax < (size_t)nz + 1) cholmod_free_sparse(&h->fa, &h->c);
  if (!h->fa) {
    h->fa = cholmod_allocate_sparse(n, n, (size_t)(sp[n] > nz ? sp[n] : nz) + 1, 1, 1, 1,
                                    CHOLMOD_REAL, &h->c);
    if (!h->fa) return fail(h, 8, "allocate_sparse (active matrix)");
  }
  A = h->fa;
  pa = (int *)A->p; ia = (int *)A->i; xa = (double *)A->x;
  nz = 0;
  /* column k of the upper triangle of P A P': the active entries, rows increasing; an
   * inactive position is an identity column */
  for (k = 0; k < n; k++) {
    pa[k] = nz;
    if (!actp[k]) { ia[nz] = k; xa[nz] = 1.0; nz++; continue; }
    for (e = sp[k]; e < sp[k + 1]; e++) {
      /* stored always, kept when active (no data-dependent branch; room: sp[k + 1] - sp[k]) */
      a = si[e];
      ia[nz] = a; xa[nz] = h->v[h->ss[e]];
      nz += actp[a];
    }
  }
  pa[n] = nz;
  /* the numeric factor of this analysis (h->l: freed with the analysis) is refactorised in place (cholmod_rowfac resets its
   * columns and reuses their storage: no allocation, no page faults); otherwise a new one
   * from the symbolic analysis. From pack_min positions on, a new factor starts as the
   * packed identity (as in cholmod_factorize) and its columns grow as rowfac fills them;
   * below, rowfac gives each column the analysed count plus room at once (no column moves;
   * at 10^5 agents that took about twice the memory of the factor) */
  if (!h->l) {
    h->l = cholmod_copy_factor(h->sym, &h->c);
    if (!h->l) return fail(h, 9, "copy_factor");
    if (n >= pack_min && (!cholmod_change_factor(CHOLMOD_REAL, 0, 0, 1, 1, h->l, &h->c) ||
                          h->c.status < CHOLMOD_OK)) {
      cholmod_free_factor(&h->l, &h->c); return fail(h, 9, "change_factor");
    }
  }
  k = cholmod_rowfac(A, NULL, beta, 0, (size_t)n, h->l, &h->c);
  if (k && h->c.status >= CHOLMOD_OK && h->l->minor < (size_t)n) {
    /* A is positive semidefinite: the pivot of a row dependent on the earlier ones is
     * round-off, or an exact zero, after which rowfac sets every later pivot to zero (and
     * skips those columns), so that independent rows would read as dependent. Then once more
     * with pivots of magnitude below 1e-14 of the largest diagonal entry set to that bound,
     * with their sign (the entries below such a pivot are round-off and stay small); the
     * caller still finds those rows dependent by their pivots (cr_chol_pivots). The updates
     * keep dbound 0. */
    for (j = 0; j < n; j++)
      if (actp[j] && pa[j + 1] > pa[j] && fabs(xa[pa[j + 1] - 1]) > dmax) dmax = fabs(xa[pa[j + 1] - 1]);
    h->c.dbound = 1.0e-14 * (dmax > 0.0 ? dmax : 1.0);
    k = cholmod_rowfac(A, NULL, beta, 0, (size_t)n, h->l, &h->c);
    h->c.dbound = 0.0;
    h->n_bounded++;
  }
  /* CHOLMOD_NOT_POSDEF / DSMALL are warnings: the caller inspects the pivots (cr_chol_pivots) */
  if (!k || h->c.status < CHOLMOD_OK) {
    /* a failed rowfac may leave the factor symbolic: never refactorised in place */
    cholmod_free_factor(&h->l, &h->c); h->lstale = 0;
    return fail(h, 10, "rowfac");
  }
  if (h->l->is_super || h->l->is_ll || h->l->xtype != CHOLMOD_REAL) {
    /* (h->l, when it exists, is a real simplicial LDL' factor of this analysis) */
    cholmod_free_factor(&h->l, &h->c); h->lstale = 0;
    snprintf(h->msg, sizeof h->msg, "CHOLMOD returned a supernodal, LL' or non-real factor"); return 11;
  }
  h->lstale = 0;
  h->napos = 0;
  for (k = 0; k < n; k++)
    if (actp[k]) h->apos[h->napos++] = k;
  memset(h->xw, 0, (size_t)n * sizeof(double));
  return 0;
}

/* Pivots D(i,i) of the current factor, in the caller's numbering: d [n]. */
int cr_chol_pivots(void *hp, double *d) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int j, *lp, *p;
  double *lx;
  if (!have_factor(h)) { snprintf(h->msg, sizeof h->msg, "cr_chol_pivots without a factor"); return 12; }
  lp = (int *)h->l->p; lx = (double *)h->l->x; p = (int *)h->l->Perm;
  for (j = 0; j < h->n; j++) d[p[j]] = lx[lp[j]];
  return 0;
}

/* Add row/column t (0-based) to the factor; its entries are (idx[q], val[q]), q < nz, over the
 * active rows and t itself (others are ignored). On return *pivot is the new D(t,t). */
int cr_chol_rowadd(void *hp, int t, int nz, const int *idx, const double *val, double *pivot) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int q, cnt = 0, k, *ri, *rp, *lp;
  double *rx;
  if (!have_factor(h)) { snprintf(h->msg, sizeof h->msg, "cr_chol_rowadd without a factor"); return 13; }
  if (h->active[t]) { snprintf(h->msg, sizeof h->msg, "cr_chol_rowadd: row %d already active", t + 1); return 14; }
  if (!h->inset[t]) { snprintf(h->msg, sizeof h->msg, "cr_chol_rowadd: row %d is outside the analysed set", t + 1); return 27; }
  rp = (int *)h->r->p; ri = (int *)h->r->i; rx = (double *)h->r->x;
  for (q = 0; q < nz; q++) {
    k = idx[q];
    if (k == t || h->active[k]) { ri[cnt] = h->iperm[k]; rx[cnt] = val[q]; cnt++; }
  }
  rp[0] = 0; rp[1] = cnt;
  h->r->sorted = 0;
  k = h->iperm[t];
  if (!cholmod_rowadd((size_t)k, h->r, h->l, &h->c) || h->c.status < CHOLMOD_OK) {
    /* a failed rowadd may leave L half modified (or symbolic): never used again */
    cholmod_free_factor(&h->l, &h->c); h->lstale = 0; h->napos = 0;
    return fail(h, 15, "rowadd");
  }
  h->active[t] = 1;
  {
    int lo = 0, hi = h->napos;
    while (lo < hi) { int mid = (lo + hi) / 2; if (h->apos[mid] < k) lo = mid + 1; else hi = mid; }
    memmove(h->apos + lo + 1, h->apos + lo, (size_t)(h->napos - lo) * sizeof(int));
    h->apos[lo] = k; h->napos++;
  }
  lp = (int *)h->l->p;
  *pivot = ((double *)h->l->x)[lp[k]];
  return 0;
}

/* s = w' A^{-1} w for the column w = (idx[q], val[q]), q < nz, restricted to the active rows
 * other than t: the part of M(t,t) that the active rows explain (the pivot row t would get is
 * M(t,t) - s). One sparse forward solve y = L^{-1} P w, s = sum y_j^2 / D(j,j). Below
 * reach_min positions: a scan of the active positions from the first nonzero of w on.
 * From reach_min on: over the reach of w only, the union of the paths from w's nonzeros to
 * the root of the elimination tree of the current factor (the parent of column j is its
 * first off-diagonal row, as cholmod_rowadd itself takes it), in topological order (the
 * paths stacked depth first, no sort). A fill outside the reach (never expected) means the
 * tree did not bound the pattern: the scan is done instead, never a wrong pivot. */
static double schur_scan(cr_chol_t *h, int t, int nz, const int *idx, const double *val, int keep) {
  int q, k, j, p, i, jmin = h->n, lo, hi, *lp = (int *)h->l->p, *li = (int *)h->l->i;
  int *lnz = (int *)h->l->nz;
  double *lx = (double *)h->l->x, *y = h->yw, yj, acc = 0.0;
  for (q = 0; q < nz; q++) {
    k = idx[q];
    if (k == t || !h->active[k]) continue;
    p = h->iperm[k];
    y[p] += val[q];
    if (p < jmin) jmin = p;
  }
  /* the active positions from jmin on (the columns there reach no inactive position but by
   * exact zeros, as in cr_chol_solve) */
  lo = 0; hi = h->napos;
  while (lo < hi) { int mid = (lo + hi) / 2; if (h->apos[mid] < jmin) lo = mid + 1; else hi = mid; }
  if (keep) for (i = 0; i < lo; i++) h->xw[h->apos[i]] = 0.0;
  for (i = lo; i < h->napos; i++) {
    j = h->apos[i];
    yj = y[j];
    if (keep) h->xw[j] = yj;
    if (yj == 0.0) continue;
    y[j] = 0.0;
    acc += yj * yj / lx[lp[j]];
    {
      const int *ip = li + lp[j] + 1;
      const double *xp = lx + lp[j] + 1;
      int c = lnz[j] - 1;
#pragma GCC unroll 4
      for (p = 0; p < c; p++) y[ip[p]] -= xp[p] * yj;
    }
  }
  return acc;
}

/* The backward half of a solve, L' x = D^{-1} y, from the forward values y in xw (active
 * positions; xw keeps x there): x in the caller's rows, set on the active rows only. The one
 * backward loop of the solves (cr_chol_solve, cr_chol_unit_solve, cr_chol_schur's alpha). */
static inline __attribute__((always_inline)) void back_solve(cr_chol_t *h, double *x) {
  int i, j, p, c, *lp = (int *)h->l->p, *li = (int *)h->l->i, *lnz = (int *)h->l->nz;
  double *lx = (double *)h->l->x, *y = h->xw, yj;
  for (i = h->napos - 1; i >= 0; i--) {
    const int *ip;
    const double *xp;
    j = h->apos[i];
    yj = y[j] / lx[lp[j]];
    ip = li + lp[j] + 1; xp = lx + lp[j] + 1; c = lnz[j] - 1;
#pragma GCC unroll 4
    for (p = 0; p < c; p++) yj -= xp[p] * y[ip[p]];
    y[j] = yj;
    x[h->rowof[j]] = yj;
  }
}

int cr_chol_schur(void *hp, int t, int nz, const int *idx, const double *val, int reach_min,
                  double *s, double *x) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int q, k, j, p, n, len, top, bad = 0, *lp, *li, *lnz, *mk, *stk;
  double *lx, *y, yj, acc = 0.0;
  if (!have_factor(h)) { snprintf(h->msg, sizeof h->msg, "cr_chol_schur without a factor"); return 21; }
  if (h->n < reach_min) {
    *s = schur_scan(h, t, nz, idx, val, x != NULL);
    if (x) back_solve(h, x);
    return 0;
  }
  n = h->n; y = h->yw;
  lp = (int *)h->l->p; li = (int *)h->l->i; lnz = (int *)h->l->nz; lx = (double *)h->l->x;
  mk = h->mk; stk = h->stk;
  /* each path is collected at the bottom of stk, then moved to the stack at its top */
  top = n;
  for (q = 0; q < nz; q++) {
    k = idx[q];
    if (k == t || !h->active[k]) continue;
    p = h->iperm[k];
    y[p] += val[q];
    for (len = 0, j = p; j >= 0 && !mk[j]; j = lnz[j] > 1 ? li[lp[j] + 1] : -1) {
      mk[j] = 1; stk[len++] = j;
    }
    while (len > 0) stk[--top] = stk[--len];
  }
  /* with x: the forward values kept in xw (zero elsewhere on the active positions) */
  if (x) for (q = 0; q < h->napos; q++) h->xw[h->apos[q]] = 0.0;
  for (q = top; q < n; q++) {
    j = stk[q];
    yj = y[j];
    if (x) h->xw[j] = yj;
    if (yj == 0.0) continue;
    y[j] = 0.0;
    acc += yj * yj / lx[lp[j]];
    for (p = lp[j] + 1; p < lp[j] + lnz[j]; p++) {
      if (!mk[li[p]]) bad = 1;
      y[li[p]] -= lx[p] * yj;
    }
  }
  for (q = top; q < n; q++) { mk[stk[q]] = 0; y[stk[q]] = 0.0; }
  if (bad) {
    memset(y, 0, (size_t)n * sizeof(double));
    h->n_schur_scan++;
    *s = schur_scan(h, t, nz, idx, val, x != NULL);
    if (x) back_solve(h, x);
    return 0;
  }
  *s = acc;
  if (x) back_solve(h, x);
  return 0;
}

/* Smallest pivot D(i,i) over the active rows (1 when none is active). */
double cr_chol_min_pivot(void *hp) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int j, *lp, *p;
  double *lx, d = 1.0;
  if (!have_factor(h)) return 0.0;
  lp = (int *)h->l->p; lx = (double *)h->l->x; p = (int *)h->l->Perm;
  for (j = 0; j < h->n; j++)
    if (h->active[p[j]] && !(lx[lp[j]] >= d)) d = lx[lp[j]];
  return d;
}

/* Clear the marks of the deletion's first n positions (rows t[0..n-1]). */
static void unmark(cr_chol_t *h, int n, const int *t) {
  int q;
  for (q = 0; q < n; q++) h->mk[h->iperm[t[q]]] = 0;
}

/* Delete the rows/columns t[0..nt-1] (0-based slots, active, distinct) from the factor: they
 * become identity rows, in one multiple-rank update. With S the deleted positions and R the
 * others, A = L D L' gives A(R,R) = L(R,R) D(R) L(R,R)' + L(R,S) D(S) L(R,S)', and L(R,R) (the
 * factor with the rows and columns of S taken out) is unit lower triangular: so the rows of S
 * leave every column, the columns of S become identity columns (D = 1, entries zero, as
 * cholmod_rowdel leaves them), and cholmod_updown adds C C' with C = L(R,S) sqrt(D(S)) (the
 * columns of S as they were, their rows in S left out). For one row this is what cholmod_rowdel
 * does (a rank-one update with column k); for several, one call of rank nt walks the union of
 * their elimination-tree paths once (measured: 3-4% fewer instructions per step on
 * congested150 than a cholmod_rowdel per row). The pattern of row k of L is bounded by its row
 * subtree in the elimination tree of P M P' (permuted_etree); the deleted rows are taken out of
 * their columns (the columns keep their order and their room), so that the solves, the Schur
 * tests and the later updates no longer visit them. The pattern stays that of a Cholesky
 * factor: the rows leave every column at once, and a column j whose parent (first
 * off-diagonal row) was deleted has the rest of its pattern in that column's, so the next row
 * of column j, its new parent, holds every row after it (the fill of eliminating the deleted
 * rows): cholmod_rowadd and cholmod_updown, which take the elimination tree from the pattern,
 * see a valid one, and C's columns lie in it. The marks mk (zero between calls, shared with
 * the Schur test) flag S during the call. Refusals (a row not active or given twice, a pivot
 * that is not positive) come before L is touched; a failure once L is modified frees the
 * factor (the caller's next cr_chol_factor builds a new one). */
int cr_chol_rowdel(void *hp, int nt, const int *t) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int q, k, j, p, e, nc, *rp, *ri, *lp, *li, *lnz, *mk, *cp, *ci, rc;
  double *lx, *cx, dk, sd;
  if (!have_factor(h)) { snprintf(h->msg, sizeof h->msg, "cr_chol_rowdel without a factor"); return 16; }
  if (nt <= 0) return 0;
  lp = (int *)h->l->p; li = (int *)h->l->i; lnz = (int *)h->l->nz; lx = (double *)h->l->x;
  mk = h->mk;
  /* checks (all of them before L is touched), the deleted positions marked in mk, and the
   * room of C */
  nc = 0;
  for (q = 0; q < nt; q++) {
    if (t[q] < 0 || t[q] >= h->n || !h->active[t[q]] || mk[h->iperm[t[q]]]) {
      unmark(h, q, t);
      snprintf(h->msg, sizeof h->msg, "cr_chol_rowdel: row %d not active (or given twice)", t[q] + 1);
      return 17;
    }
    k = h->iperm[t[q]];
    dk = lx[lp[k]];
    if (!(dk > 0.0)) {
      unmark(h, q, t);
      snprintf(h->msg, sizeof h->msg, "cr_chol_rowdel: pivot %g of row %d is not positive", dk, t[q] + 1);
      return 18;
    }
    mk[k] = 1;
    nc += lnz[k] - 1;
  }
  if (!h->cu || (int)h->cu->ncol < nt || (int)h->cu->nzmax < nc) {
    size_t ncol = (size_t)nt + 8, nzmax = (size_t)nc + (size_t)nc / 2 + 64;
    if (h->cu) cholmod_free_sparse(&h->cu, &h->c);
    h->cu = cholmod_allocate_sparse((size_t)h->n, ncol, nzmax, 1, 1, 0, CHOLMOD_REAL, &h->c);
    if (!h->cu) {
      unmark(h, nt, t);
      return fail(h, 18, "allocate_sparse (rowdel)");
    }
  }
  /* C = L(R, S) sqrt(D(S)) from the columns as they are (rows of S left out), then the
   * columns of S become identity columns (their entries zero, as cholmod_rowdel leaves them) */
  cp = (int *)h->cu->p; ci = (int *)h->cu->i; cx = (double *)h->cu->x;
  cp[0] = 0; nc = 0;
  for (q = 0; q < nt; q++) {
    k = h->iperm[t[q]];
    sd = sqrt(lx[lp[k]]);
    e = lp[k] + lnz[k];
    for (p = lp[k] + 1; p < e; p++) {
      if (!mk[li[p]]) { ci[nc] = li[p]; cx[nc] = lx[p] * sd; nc++; }
      lx[p] = 0.0;
    }
    lx[lp[k]] = 1.0;
    cp[q + 1] = nc;
  }
  h->cu->ncol = (size_t)nt;
  /* rows S leave every column of their row subtree */
  rc = 0;
  for (q = 0; q < nt && rc == 0; q++) {
    k = h->iperm[t[q]];
    if (!cholmod_row_subtree(h->pm, NULL, (size_t)k, h->parent, h->rpat, &h->c) || h->c.status < CHOLMOD_OK) {
      rc = fail(h, 25, "row_subtree"); break;
    }
    rp = (int *)h->rpat->p; ri = (int *)h->rpat->i;
    for (p = rp[0]; p < rp[1]; p++) {
      int pp;
      j = ri[p];
      e = lp[j] + lnz[j];
      for (pp = lp[j] + 1; pp < e && li[pp] != k; pp++) {}
      if (pp == e) continue;
      memmove(li + pp, li + pp + 1, (size_t)(e - pp - 1) * sizeof(int));
      memmove(lx + pp, lx + pp + 1, (size_t)(e - pp - 1) * sizeof(double));
      lnz[j]--;
    }
  }
  unmark(h, nt, t);
  for (q = 0; q < nt; q++) {
    int lo = 0, hi = h->napos;
    k = h->iperm[t[q]];
    h->active[t[q]] = 0;
    while (lo < hi) { int mid = (lo + hi) / 2; if (h->apos[mid] < k) lo = mid + 1; else hi = mid; }
    if (lo < h->napos && h->apos[lo] == k) {
      memmove(h->apos + lo, h->apos + lo + 1, (size_t)(h->napos - lo - 1) * sizeof(int));
      h->napos--;
    }
    h->xw[k] = 0.0;
  }
  if (rc == 0 && nc > 0 && (!cholmod_updown(1, h->cu, h->l, &h->c) || h->c.status < CHOLMOD_OK))
    rc = fail(h, 18, "updown (rowdel)");
  if (rc != 0) {
    /* L is half modified (or, out of memory, symbolic): no factor until the next one */
    cholmod_free_factor(&h->l, &h->c); h->lstale = 0;
    return rc;
  }
  return 0;
}

/* x = A^{-1} b in the caller's rows (b, x [nrow]; may alias; identity on the rows without a
 * slot): x = P' L^{-T} D^{-1} L^{-1} P b on the factor's arrays (simplicial LDL', unit
 * diagonal stored first in each column; P maps factor positions to the caller's rows and
 * slots without a row get zero). The same arithmetic as
 * cholmod_solve2 without its per-call set-up, which dominated the cost for the small factors
 * of the active-set iterations; a zero or NaN pivot gives a NaN solution, which the caller's
 * KKT check turns into a failed (never silent) solve. */
int cr_chol_solve(void *hp, const double *b, double *x) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int i, j, p, na, *lp, *li, *lnz, *ap, *rowof;
  double *lx, *y, yj;
  if (!have_factor(h)) { snprintf(h->msg, sizeof h->msg, "cr_chol_solve without a factor"); return 19; }
  if (h->l->is_super || h->l->is_ll || h->l->xtype != CHOLMOD_REAL) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_solve: factor is not a real simplicial LDL'");
    return 20;
  }
  y = h->xw; na = h->napos; ap = h->apos; rowof = h->rowof;
  lp = (int *)h->l->p; li = (int *)h->l->i; lnz = (int *)h->l->nz; lx = (double *)h->l->x;
  /* identity rows (inactive slots, rows without a slot): x = b */
  if (x != b) memcpy(x, b, (size_t)h->nrow * sizeof(double));
  /* the active positions only: the columns of L there reach no other position (A has no
   * entry between active and inactive rows; cr_chol_rowdel takes a deleted row out of the
   * pattern, and any other entry in an inactive row is an exact zero, which meets the zeros
   * kept in y at inactive positions) */
  for (i = 0; i < na; i++) { j = ap[i]; y[j] = b[rowof[j]]; }
  for (i = 0; i < na; i++) {            /* L y = P b */
    const int *ip;
    const double *xp;
    int c;
    j = ap[i];
    yj = y[j];
    if (yj == 0.0) continue;
    ip = li + lp[j] + 1; xp = lx + lp[j] + 1; c = lnz[j] - 1;
#pragma GCC unroll 4
    for (p = 0; p < c; p++) y[ip[p]] -= xp[p] * yj;
  }
  back_solve(h, x);                     /* L' x = D^{-1} y, the result scattered to x */
  return 0;
}

/* x = A^{-1} e_s in the caller's rows (x [nrow], set on the active rows only) for the active slot
 * s, and *xss = x at s, the diagonal entry of A^{-1}: L y = e_k (k the position of s) has its
 * nonzeros on the path from k to the root of the elimination tree of the current factor (the
 * parent of column j is its first off-diagonal row, as in the Schur test), so the forward solve
 * visits that path only; the backward solve is the full one of cr_chol_solve. */
int cr_chol_unit_solve(void *hp, int s, double *x, double *xss) {
  cr_chol_t *h = (cr_chol_t *)hp;
  int i, j, k, p, c, na, *lp, *li, *lnz, *ap;
  double *lx, *y, yj;
  if (!have_factor(h)) { snprintf(h->msg, sizeof h->msg, "cr_chol_unit_solve without a factor"); return 19; }
  if (s < 0 || s >= h->n || !h->active[s]) {
    snprintf(h->msg, sizeof h->msg, "cr_chol_unit_solve: slot %d not active", s + 1);
    return 17;
  }
  y = h->xw; na = h->napos; ap = h->apos;
  lp = (int *)h->l->p; li = (int *)h->l->i; lnz = (int *)h->l->nz; lx = (double *)h->l->x;
  for (i = 0; i < na; i++) y[ap[i]] = 0.0;
  k = h->iperm[s];
  y[k] = 1.0;
  for (j = k;;) {                       /* L y = e_k along the path from k */
    const int *ip = li + lp[j] + 1;
    const double *xp = lx + lp[j] + 1;
    yj = y[j];
    c = lnz[j] - 1;
    if (c <= 0) break;
    for (p = 0; p < c; p++) y[ip[p]] -= xp[p] * yj;
    j = ip[0];
  }
  back_solve(h, x);                     /* L' x = D^{-1} y */
  *xss = y[k];
  return 0;
}

/* Schur tests whose elimination-tree reach missed a fill (then done by the scan). */
long cr_chol_n_schur_scan(void *hp) {
  cr_chol_t *h = (cr_chol_t *)hp;
  return h->n_schur_scan;
}

/* Factorisations redone with bounded pivots since the handle was created (cr_chol_factor). */
long cr_chol_n_bounded(void *hp) {
  cr_chol_t *h = (cr_chol_t *)hp;
  return h->n_bounded;
}

/* Stored off-diagonal entries of the current factor in the row of slot t (0-based; 0 without
 * a factor): a test of cr_chol_rowdel, which leaves none in a deleted row. O(nnz(L)). */
long cr_chol_row_entries(void *hp, int t) {
  cr_chol_t *h = (cr_chol_t *)hp;
  long s = 0;
  int j, p, k, *lp, *li, *lnz;
  if (!have_factor(h) || t < 0 || t >= h->n) return 0;
  k = h->iperm[t];
  lp = (int *)h->l->p; li = (int *)h->l->i; lnz = (int *)h->l->nz;
  for (j = 0; j < k; j++)
    for (p = lp[j] + 1; p < lp[j] + lnz[j]; p++)
      if (li[p] == k) s++;
  return s;
}

/* Number of stored entries of the factor (nnz(L) including the diagonal). */
long cr_chol_factor_nnz(void *hp) {
  cr_chol_t *h = (cr_chol_t *)hp;
  long s = 0;
  int j, *nzc;
  if (!have_factor(h)) return 0;
  nzc = (int *)h->l->nz;
  for (j = 0; j < h->n; j++) s += nzc[j];
  return s;
}
