// The occlusion queries' threshold quads write nothing but the depth test.
void main() {}
