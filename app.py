"""CMM error lab: Streamlit entry page (placeholder until the app lands)."""

import streamlit as st

st.set_page_config(page_title="CMM error lab", layout="wide")
st.title("CMM error lab")
st.write("Core package under construction.")
