// Writes small luminance/chroma (Y, RY, BY [, A]) OpenEXR test fixtures with
// Imf::RgbaOutputFile and dumps, for each, as raw little-endian float32:
//   NAME.src.f32   the RGBA given to the writer (w*h*4, half values widened)
//   NAME.rgba.f32  Imf::RgbaInputFile's own YC->RGB reconstruction (w*h*4)
//   NAME.y.f32     stored Y channel (w*h)
//   NAME.ry.f32    stored RY channel ((w/2)*(h/2))
//   NAME.by.f32    stored BY channel ((w/2)*(h/2))
//   NAME.a.f32     stored A channel (w*h), YCA files only
// Build: g++ -O1 -std=c++17 gen.cpp $(pkg-config --cflags --libs OpenEXR) -o gen
#include <ImfRgbaFile.h>
#include <ImfInputFile.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfChannelList.h>
#include <ImfStandardAttributes.h>
#include <ImathBox.h>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

using namespace Imf;
using namespace Imath;

struct Px { float r, g, b, a; };
using PixelFn = std::function<Px (int x, int y)>; // x, y relative to data window

static void dump (const std::string& path, const std::vector<float>& v)
{
    FILE* f = fopen (path.c_str (), "wb");
    if (!f) { perror (path.c_str ()); exit (1); }
    // x86-64 is little-endian: write as is.
    fwrite (v.data (), sizeof (float), v.size (), f);
    fclose (f);
}

static FILE* manifest;

static bool make (const std::string& name, int w, int h, V2i origin, RgbaChannels ch,
                  Compression comp, const Chromaticities* chroma, PixelFn fn)
{
    std::string file = name + ".exr";
    Box2i dw (origin, origin + V2i (w - 1, h - 1));
    Box2i disp (V2i (std::min (0, origin.x), std::min (0, origin.y)),
                V2i (std::max (origin.x + w - 1, w - 1), std::max (origin.y + h - 1, h - 1)));
    std::vector<Rgba> src (size_t (w) * h);
    std::vector<float> srcf;
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
        {
            Px p = fn (x, y);
            Rgba& q = src[size_t (y) * w + x];
            q = Rgba (p.r, p.g, p.b, p.a);
            srcf.insert (srcf.end (), {float (q.r), float (q.g), float (q.b), float (q.a)});
        }
    try
    {
        Header hd (disp, dw, 1, V2f (0, 0), 1, INCREASING_Y, comp);
        if (chroma) addChromaticities (hd, *chroma);
        RgbaOutputFile out (file.c_str (), hd, ch);
        out.setFrameBuffer (src.data () - origin.x - size_t (origin.y) * w, 1, w);
        out.writePixels (h);
    }
    catch (const std::exception& e)
    {
        fprintf (stderr, "%s: writing failed: %s\n", file.c_str (), e.what ());
        fprintf (manifest, "%s: NOT WRITTEN (%s)\n", file.c_str (), e.what ());
        remove (file.c_str ());
        return false;
    }
    dump (name + ".src.f32", srcf);

    // (b) the library's own reconstruction
    {
        RgbaInputFile in (file.c_str ());
        Box2i d = in.dataWindow ();
        std::vector<Rgba> px (size_t (w) * h);
        in.setFrameBuffer (px.data () - d.min.x - size_t (d.min.y) * w, 1, w);
        in.readPixels (d.min.y, d.max.y);
        std::vector<float> v;
        for (auto& p : px) v.insert (v.end (), {float (p.r), float (p.g), float (p.b), float (p.a)});
        dump (name + ".rgba.f32", v);
    }
    // raw stored channels
    {
        InputFile in (file.c_str ());
        const Header& hdr = in.header ();
        Box2i d = hdr.dataWindow ();
        int cw = w / 2, chh = h / 2;
        std::vector<half> Y (size_t (w) * h), A (size_t (w) * h), RY (size_t (cw) * chh), BY (size_t (cw) * chh);
        FrameBuffer fb;
        size_t hs = sizeof (half);
        fb.insert ("Y", Slice (HALF, (char*) (Y.data () - d.min.x - ptrdiff_t (d.min.y) * w), hs, hs * w, 1, 1));
        bool hasA = hdr.channels ().findChannel ("A") != nullptr;
        if (hasA)
            fb.insert ("A", Slice (HALF, (char*) (A.data () - d.min.x - ptrdiff_t (d.min.y) * w), hs, hs * w, 1, 1));
        // With sampling 2 the sample of pixel (x, y) lies at base + (x/2)*xStride + (y/2)*yStride.
        ptrdiff_t off = -(d.min.x / 2) - ptrdiff_t (d.min.y / 2) * cw;
        fb.insert ("RY", Slice (HALF, (char*) (RY.data () + off), hs, hs * cw, 2, 2));
        fb.insert ("BY", Slice (HALF, (char*) (BY.data () + off), hs, hs * cw, 2, 2));
        in.setFrameBuffer (fb);
        in.readPixels (d.min.y, d.max.y);
        auto widen = [] (const std::vector<half>& v) {
            std::vector<float> o (v.size ());
            for (size_t i = 0; i < v.size (); ++i) o[i] = v[i];
            return o;
        };
        dump (name + ".y.f32", widen (Y));
        dump (name + ".ry.f32", widen (RY));
        dump (name + ".by.f32", widen (BY));
        if (hasA) dump (name + ".a.f32", widen (A));

        std::string chans;
        for (auto i = hdr.channels ().begin (); i != hdr.channels ().end (); ++i)
            chans += std::string (" ") + i.name () + "(" + std::to_string (i.channel ().xSampling) +
                     "x" + std::to_string (i.channel ().ySampling) + (i.channel ().pLinear ? ",pLinear" : "") + ")";
        const char* cn = comp == ZIP_COMPRESSION ? "ZIP" : comp == NO_COMPRESSION ? "NONE" : "?";
        fprintf (manifest, "%s: %dx%d dataWindow=(%d,%d)-(%d,%d) compression=%s channels:%s chromaticities=%s\n",
                 file.c_str (), w, h, d.min.x, d.min.y, d.max.x, d.max.y, cn, chans.c_str (),
                 chroma ? "explicit" : "absent(Rec.709 default)");
    }
    return true;
}

// deterministic scenes -----------------------------------------------------------

static Px patches (int x, int y)
{
    // 2-pixel-wide colour bars, rows scaled by exposure; row 0..1 include a grey bar.
    static const float bars[4][3] = {{1.0f, 0.1f, 0.05f}, {0.1f, 0.8f, 0.2f}, {0.05f, 0.2f, 1.2f}, {0.5f, 0.5f, 0.5f}};
    const float* c = bars[(x / 2) % 4];
    float k = 0.25f + 0.5f * y;
    return {c[0] * k, c[1] * k, c[2] * k, 1.0f};
}

static Px patches_alpha (int x, int y)
{
    Px p = patches (7 - x, y);
    p.g += 0.03f * x;
    p.a = float (x + y) / 12.0f;
    return p;
}

static Px small10 (int x, int y)
{
    // hue ramp along x, brightness ramp along y
    float t = x / 9.0f;
    return {0.2f + 1.5f * t, 0.9f - 0.6f * t + 0.05f * y, 0.3f + 0.4f * float ((x * 7 + y * 3) % 5) / 4.0f, 1.0f};
}

static Px big (int x, int y)
{
    // smooth gradients everywhere...
    float u = x / 59.0f, v = y / 39.0f;
    Px p = {0.05f + 2.0f * u * u, 0.1f + 1.5f * v, 0.2f + 0.8f * (0.5f + 0.5f * std::sin (6.2831853f * (u + 0.5f * v))), 1.0f};
    // ...a sharp saturated red/cyan edge (vertical edge at odd column 35, rows 8..31)...
    if (y >= 8 && y < 32)
    {
        if (x >= 35 && x < 48) p = {4.0f, 0.02f, 0.02f, 1.0f};
        else if (x >= 48) p = {0.01f, 0.6f, 0.7f, 1.0f};
    }
    // ...a horizontal coloured edge at odd row 25 on the left...
    if (y >= 25 && y < 37 && x < 20) p = {0.05f, 0.05f, 2.5f, 1.0f};
    // ...a neutral grey block (R == G == B: chroma stored as exactly 0)...
    if (x >= 22 && x < 30 && y >= 2 && y < 12) p = {0.18f, 0.18f, 0.18f, 1.0f};
    // ...and a single bright saturated pixel and a black one.
    if (x == 10 && y == 10) p = {0.0f, 16.0f, 0.0f, 1.0f};
    if (x == 12 && y == 5) p = {0.0f, 0.0f, 0.0f, 1.0f};
    return p;
}

static Px wide (int x, int y)
{
    float t = (x + 0.5f) / 16.0f, s = (y + 0.5f) / 12.0f;
    return {0.8f * t + 0.05f, 0.6f * (1 - t) + 0.1f * s, 0.9f * s + 0.02f, 1.0f};
}

static Px bottom (int x, int y)
{
    // exercises the bottom-edge quirk: the virtual row below the last one takes its Y
    // from the second-last row (black here), not from the last (bright, saturated)
    if (y == 2) return {0.0f, 0.0f, 0.0f, 1.0f};
    if (y == 3) return {2.0f + 0.25f * x, 0.05f, 0.1f + 0.1f * (x % 3), 1.0f};
    return {1.0f + 0.125f * x, 0.04f, 0.08f + 0.01f * y, 1.0f};
}

int main ()
{
    manifest = fopen ("MANIFEST.txt", "w");
    fprintf (manifest, "Generated by gen.cpp with OpenEXR %s (Debian libopenexr-dev). Raw dumps are little-endian float32.\n"
                       "NAME.src.f32: writer input RGBA (w*h*4); NAME.rgba.f32: RgbaInputFile reconstruction RGBA (w*h*4);\n"
                       "NAME.y.f32 (w*h), NAME.ry.f32 / NAME.by.f32 ((w/2)*(h/2)), NAME.a.f32 (w*h, YCA only): stored channels.\n",
             OPENEXR_VERSION_STRING);
    make ("yc_8x6_zip", 8, 6, V2i (0, 0), WRITE_YC, ZIP_COMPRESSION, nullptr, patches);
    make ("yca_8x6_none", 8, 6, V2i (0, 0), WRITE_YCA, NO_COMPRESSION, nullptr, patches_alpha);
    make ("yc_7x5_zip", 7, 5, V2i (0, 0), WRITE_YC, ZIP_COMPRESSION, nullptr, small10); // expected to fail
    make ("yc_10x6_zip", 10, 6, V2i (0, 0), WRITE_YC, ZIP_COMPRESSION, nullptr, small10); // 5x3 chroma grid
    make ("yc_12x8_rle", 12, 8, V2i (0, 0), WRITE_YC, RLE_COMPRESSION, nullptr, patches);
    make ("yc_10x6_offset_none", 10, 6, V2i (4, -2), WRITE_YC, NO_COMPRESSION, nullptr, small10);
    make ("yc_60x40_zip", 60, 40, V2i (0, 0), WRITE_YC, ZIP_COMPRESSION, nullptr, big);
    Chromaticities rec2020 (V2f (0.708f, 0.292f), V2f (0.170f, 0.797f), V2f (0.131f, 0.046f), V2f (0.3127f, 0.3290f));
    make ("yc_16x12_rec2020_zip", 16, 12, V2i (0, 0), WRITE_YC, ZIP_COMPRESSION, &rec2020, wide);
    make ("yc_8x4_bottom_zip", 8, 4, V2i (0, 0), WRITE_YC, ZIP_COMPRESSION, nullptr, bottom);
    fclose (manifest);
    return 0;
}
