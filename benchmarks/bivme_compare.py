import sys
from cardionurbs import load_study, reconstruct, measure
s=load_study('/work/shared/data/bivme-patient1')
m=reconstruct(s); r=measure(m)
ref={'LVEDV (mL)':179.0,'RVEDV (mL)':167.8,'LVM (g)':131.3,'RVM (g)':51.9,'LVESV (mL)':72.0,'RVESV (mL)':76.7}
print(m.ed_frame, m.es_frame)
for k,v in ref.items(): print(f"{k:12s} {r[k]:7.1f} biv-me {v:6.1f} {100*(r[k]-v)/v:+6.1f}%")
print('MR RegFrac', round(r['MR RegFrac (%)'],1))
res=m.residual_table()
print(res.groupby(['structure','view'])[['max_mm','max_px']].max())
